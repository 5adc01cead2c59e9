"""``snan-hil compare``: the paper's Fig. 10C/D on a board (or the emulator).

Programs each weight set, runs sw_noastro / sw_astro / hw_noastro / hw_astro x sets x launches,
prints the table and the speed/energy report, writes CSV/JSON/PNG into --out. The launch model
is checked against the training config stored in the weights file first
(:mod:`snan_hil.host.hil.trained_config`; ``--accept-config-diff`` to launch a different one).
Example: ``snan-hil compare --weights weights.npz --port emu --out results/``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.table import Table

from snan_hil.host.intervals import METHOD_TEXT, format_interval, inside_text
from snan_hil.calibration.weights_io import load_weight_set, weights_fingerprint
from snan_hil.common.errors import UserError
from snan_hil.host.checkpoint import RunFolder, check_out, open_run
from snan_hil.host.hil.synapses import (HW_MODES, check_mode_for_protocol,
                                        check_mode_for_scenarios)
from snan_hil.config import loader as configio
from snan_hil.host.hil.compare import (CompareJob, CompareRequest, adopt_old_snapshots,
                                       boards_fields, check_snapshots, compare_summary,
                                       run_software, write_outputs)
from snan_hil.host.hil.config import SCENARIOS, HilConfig, load_hil_config
from snan_hil.host.hil.report import format_si
from snan_hil.host.hil.runner import check_launches, check_layout, scenario_parts
from snan_hil.host.hil.trained_config import check_trained_config
from snan_hil.board.session import BoardSession
from snan_hil.calibration.layout import load_session_layout
from snan_hil.files.outputs import Outputs
from snan_hil.board.identity import BoardIdentity
from snan_hil.lab.fanout import BoardSet, run_on_boards
from snan_hil.lab.opener import BoardPlan, FileUse
from snan_hil.lab.group_run import run_group_job
from snan_hil.lab.runner import HostRun
from snan_hil.records.history import check_history_file
from snan_hil.tools.commands._board import file_use, plan_from_args
from snan_hil.tools.commands._boards import add_board_options, board_set, print_boards
from snan_hil.tools.commands._group import add_group_option, group_plans, group_ports
from snan_hil.tools.commands._history import add_history_arguments, recording
from snan_hil.tools.commands._options import (add_conversions_option, add_mode_option,
                                              check_conversions,
                                              add_renamed_option,
                                              check_set_conflicts)
from snan_hil.tools.commands._job import run_on_board, run_options
from snan_hil.tools.commands._run import runs_database
from snan_hil.tools.commands.train import add_accept_option, add_hil_config_arguments
from snan_hil.tools.console import console, err_console, note, progress_display
from snan_hil.tools.output_kinds import add_force_option, compare_files
from snan_hil.tools.ports import add_port_arguments
from snan_hil.tools.verdicts import print_verdicts

NAME = "compare"
HELP = "program each weight set and compare software/crossbar x astro/no-astro (paper Fig. 10C/D)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--weights", required=True, metavar="FILE",
                        help="weights from 'snan-hil train' (.npz)")
    parser.add_argument("--out", default="hil-results", metavar="DIR",
                        help="folder for compare.json, launches.csv, summary.csv, "
                             "speed_energy.csv, fig10c.png, the programming reports and the "
                             "run's checkpoint/ (see --resume)")
    parser.add_argument("--sets", type=int, default=None, metavar="N",
                        help="use the first N weight sets (default: all)")
    parser.add_argument("--weight-set", dest="only", default=None, metavar="K[,K...]",
                        help="use only these weight sets, e.g. 0,3 (default: all)")
    add_renamed_option(parser, "--only", "--weight-set K[,K...]")
    parser.add_argument("--launches", type=int,
                        default=configio.field_default(CompareRequest, "launches"),
                        help="launches per set and scenario")
    parser.add_argument("--seed", type=int, default=configio.field_default(CompareRequest, "seed"),
                        help="launch seed")
    parser.add_argument("--scenarios", default=",".join(SCENARIOS),
                        help="comma-separated subset of " + ", ".join(SCENARIOS))
    add_mode_option(parser, HW_MODES)
    add_conversions_option(parser)
    parser.add_argument("--no-program", action="store_true",
                        help="do not program (only valid with one set already on the chip)")
    parser.add_argument("--layout", default=None,
                        help="layout file of the chip (default: the port's, see program-weights)")
    parser.add_argument("--no-figure", action="store_true", help="skip fig10c.png")
    add_hil_config_arguments(parser)
    add_accept_option(parser)
    add_port_arguments(parser)
    parser.add_argument("--json", action="store_true",
                        help="print the summary as JSON (files are written anyway)")
    add_history_arguments(parser)
    add_force_option(parser)
    add_resume_option(parser)
    add_board_options(parser)
    add_group_option(parser)


def add_resume_option(parser: argparse.ArgumentParser) -> None:
    """``--resume``: continue the run whose checkpoint is in --out."""
    parser.add_argument("--resume", action="store_true",
                        help="continue the run in --out where it stopped (its checkpoint/ "
                             "records every finished part; the options must be the same); "
                             "without it a folder holding an earlier run is refused (also "
                             "with --force)")


def _parse_sets(count: int | None, only: str | None, n_sets: int) -> list[int] | None:
    if count is not None and only is not None:
        raise UserError("give --sets or --weight-set, not both")
    if count is not None:
        if not 1 <= count <= n_sets:
            raise UserError(f"--sets {count}: the file holds {n_sets} set(s); give 1..{n_sets}")
        return list(range(count))
    if only is None:
        return None
    try:
        sets = [int(x) for x in only.split(",") if x.strip()]
    except ValueError:
        raise UserError(f"--weight-set {only!r}: expected set indices like 0,2,5") from None
    for k in sets:
        if not 0 <= k < n_sets:
            raise UserError(f"--weight-set: set {k} out of range, the file holds {n_sets} "
                            f"set(s) (0..{n_sets - 1})")
    if len(set(sets)) != len(sets) or not sets:
        raise UserError(f"--weight-set {only!r}: give each set once")
    return sets


def _scenarios(args: argparse.Namespace) -> tuple[str, ...]:
    """``--scenarios``, checked (each decides ``astro.enabled`` of its launches)."""
    scen = tuple(s.strip() for s in args.scenarios.split(",") if s.strip())
    bad = [s for s in scen if s not in SCENARIOS]
    if bad or not scen:
        raise UserError(f"--scenarios: unknown {bad[0] if bad else '(empty)'}; use "
                        + ", ".join(SCENARIOS))
    for s in scen:
        check_set_conflicts(args.overrides, {"astro.enabled": (f"--scenarios ({s})",
                                                               scenario_parts(s)[1])})
    return scen


def _run_identity(args: argparse.Namespace, meta: dict[str, Any], sets: list[int] | None,
                  scen: tuple[str, ...], hil: HilConfig, session: BoardSession | None,
                  hw_mode: str | None) -> dict[str, Any]:
    """What a resumed run must share with this one (:func:`snan_hil.host.checkpoint.
    open_run`): the weights, sets, launches, seed, scenarios, config and the board (by its
    identity, not its port)."""
    return {
        "weights": {"sha256": weights_fingerprint(args.weights), "n_sets": meta["n_sets"]},
        "sets": sets if sets is not None else list(range(meta["n_sets"])),
        "launches": args.launches, "seed": args.seed, "scenarios": list(scen),
        "config": hil.to_dict(),
        "board": {**session.identity.resume_key(args.port),
                  "protocol": args.protocol, "mcu": args.mcu, "baud": args.baud,
                  "mode": hw_mode, "program": not args.no_program,
                  "layout": str(session.files.layout),
                  # (only when given: runs started without it resume as before)
                  **({"conversions": args.conversions} if args.conversions is not None
                     else {})}
        if session is not None else None,
    }


@dataclass
class _Setup:
    """A comparison as the options give it, checked before any board is opened."""

    args: argparse.Namespace
    meta: dict[str, Any]
    sets: list[int] | None
    scen: tuple[str, ...]
    hil: HilConfig
    trained: Any
    hw: bool
    n_used: int
    folder: RunFolder | None = None

    def identity(self, session: BoardSession | None, hw_mode: str | None) -> dict[str, Any]:
        return _run_identity(self.args, self.meta, self.sets, self.scen, self.hil, session,
                             hw_mode)

    def open_folder(self, out: Path, session: BoardSession | None,
                    hw_mode: str | None) -> RunFolder:
        """The run's checkpoint in ``out`` (a resumed run: the same run, or one line)."""
        self.folder = open_run(out, NAME, self.identity(session, hw_mode),
                               resume=self.args.resume)
        for line in self.trained.notes(self.args.weights):
            err_console.print(line, markup=False, highlight=False, soft_wrap=True)
        if self.folder.resumed:
            err_console.print(f"resuming the run in {out}", highlight=False, soft_wrap=True)
        return self.folder


def _setup(args: argparse.Namespace) -> _Setup:
    scen = _scenarios(args)
    check_mode_for_scenarios(scen, args.mode)            # options first, then the files
    _w, meta = load_weight_set(args.weights, 0)                 # validated before any I/O
    sets = _parse_sets(args.sets, args.only, meta["n_sets"])
    check_launches(args.launches)
    hil = load_hil_config(args.config, args.overrides)
    trained = check_trained_config(meta, hil, args.weights, accept=args.accept_config_diff)
    hw = any(s.startswith("hw_") for s in scen)
    if hw:
        check_mode_for_protocol(args.protocol, args.mode)
    n_used = len(sets) if sets is not None else meta["n_sets"]
    return _Setup(args, meta, sets, scen, hil, trained, hw, n_used)


def run(args: argparse.Namespace) -> int:
    check_conversions(args)
    setup = _setup(args)
    ports = group_ports(args, refusals=[
        (args.no_program, "--no-program works with one board (the chip holds one set); a "
                          "chip group is programmed by the comparison: leave it out"),
        (not setup.hw, "--group runs the hardware scenarios over a chip group; --scenarios "
                       "has none (give hw_noastro or hw_astro, or leave --group out)"),
        (args.mode not in (None, "on-board"),
         f"--mode {args.mode}: a chip group runs the on-board decision windows (each on the "
         "chip of its input neuron); leave --mode out")])
    if ports is not None:               # one network over a chip group (docs/multiboard.md)
        return _report(args, *_on_group(args, setup, ports))
    boards = board_set(args, use=FileUse(record=recording(args) and args.record != "off",
                                         updates_layout=True), refusals=[
        (args.no_program, "--no-program works with one board (the chip holds one set); "
                          "leave it out with --boards/--dask"),
        (not setup.hw, "--boards/--dask spread the hardware scenarios; --scenarios has none "
                       "(give hw_noastro or hw_astro, or leave --boards out)")])
    if boards is not None:              # several boards: lab.fanout (docs/multiboard.md)
        return _report(args, *_on_boards(args, setup, boards))
    if args.no_program and setup.hw and setup.n_used > 1:
        raise UserError("--no-program works with one set only (the chip holds one set); "
                        "give --sets K")
    # every output checked before any launch (docs/outputs.md); a reused --out is resumed or
    # refused (host.checkpoint)
    programs = setup.hw and not args.no_program
    plan = plan_from_args(args, use=file_use(args, record=recording(args),
                                             updates_layout=programs),
                          weights=args.weights, config=args.config) if setup.hw else None
    outs = plan.outputs if plan is not None else Outputs(
        {"--weights": args.weights, "--config": args.config}, force=args.force)
    if plan is None and recording(args) and args.history:
        check_history_file(args.history)    # software only: a file not ours, before any work
    out = check_out(outs, args.out, NAME, resume=args.resume,
                    files=compare_files(setup.sets if setup.sets is not None
                                        else list(range(setup.n_used)),
                                        programming=programs, figure=not args.no_figure))
    job = CompareJob(CompareRequest(
        args.weights, setup.hil, sets=tuple(setup.sets) if setup.sets is not None else None,
        launches=args.launches, seed=args.seed, scenarios=setup.scen, mode=_mode(args),
        program=not args.no_program, report_dir=out / "programming",
        conversions=args.conversions))
    results = _on_board(args, setup, job, plan, out) if plan is not None \
        else _software(args, setup, job, out)
    results["trained_config_check"] = setup.trained.to_dict()
    paths = write_outputs(results, out, figure=not args.no_figure)
    assert setup.folder is not None                     # opened before the first launch
    setup.folder.complete()
    return _report(args, results, paths)


def _mode(args: argparse.Namespace) -> str | None:
    return args.mode.replace("-", "_") if args.mode else None


def _on_board(args: argparse.Namespace, setup: _Setup, job: CompareJob, plan: BoardPlan,
              out: Path) -> dict[str, Any]:
    """The comparison run by the job runner on the board of ``plan``: the checkpoint opened
    once the board said who it is (and, without programming, that its layout holds the
    set); the results with the run's block."""
    if args.resume:                     # a damaged snapshot: one line, the chip unopened
        adopt_old_snapshots(out, job.unit_order())
        check_snapshots(out, plan.snapshots)

    def folder(session: BoardSession) -> RunFolder:
        hw_mode = job.mode_on(session.client)
        if args.no_program and not args.resume:  # a resumed run puts its snapshot back first
            _check_chip_holds(args, session, setup.sets)
        return setup.open_folder(out, session, hw_mode)
    done = run_on_board(args, job, plan, folder_of=folder, seed=args.seed)
    return {**done.result, "run": done.run_block()}


def _software(args: argparse.Namespace, setup: _Setup, job: CompareJob,
              out: Path) -> dict[str, Any]:
    """Software scenarios only: no board; recorded in ``--history`` or the user's runs
    database (kind ``hil``), each set committed to the checkpoint."""
    folder = setup.open_folder(out, None, None)
    with progress_display() as progress:
        options = dataclasses.replace(run_options(args, progress=progress, seed=args.seed),
                                      history=_history(args, None))
        with HostRun(job, options, port=args.port, protocol=args.protocol) as host:
            results = run_software(job, checkpoint=folder, progress=host.progress,
                                   emit=host.emit)
            host.finish("complete", results)
    return {**results, "run": host.run_block()}


def _open_folder(args: argparse.Namespace, setup: _Setup, out: Path,
                 identity: dict[str, Any]) -> RunFolder:
    """The run folder of a comparison over several boards or a chip group, opened (or
    resumed) once the boards have answered, with the weights' notes said."""
    folder = open_run(out, NAME, identity, resume=args.resume)
    setup.folder = folder
    for line in setup.trained.notes(args.weights):
        note(line)
    if folder.resumed:
        note(f"resuming the run in {out}")
    return folder


def _on_boards(args: argparse.Namespace, setup: _Setup, boards: BoardSet
               ) -> tuple[dict[str, Any], dict[str, str]]:
    """The comparison over several boards (:func:`snan_hil.lab.fanout.run_on_boards`): each
    set a group on its board, the spike measurement on one of them; recorded once here (kind
    ``hil``, in ``--history`` or the user's runs database: the launches stream of every set
    as its board ends it, the boards in its start and stop), each board's history recording
    its pulses with the same metadata. (results, written files)."""
    sets = setup.sets
    outs = Outputs({"--weights": args.weights, "--config": args.config}, force=args.force)
    out = check_out(outs, args.out, NAME, resume=args.resume,
                    files=compare_files(sets if sets is not None else list(range(setup.n_used)),
                                        programming=True, figure=not args.no_figure))
    history = None
    if recording(args):
        history = check_history_file(Path(args.history).expanduser()) if args.history \
            else runs_database()
    # absolute: a scheduler's workers need not share this folder as their working one
    job = CompareJob(CompareRequest(
        str(Path(args.weights).resolve()), setup.hil,
        sets=tuple(sets) if sets is not None else None, launches=args.launches,
        seed=args.seed, scenarios=setup.scen, mode=_mode(args), program=True,
        report_dir=out.resolve() / "programming", conversions=args.conversions))
    if args.resume:                     # a damaged snapshot: one line, no board opened
        check_snapshots(out, None)

    def opened(found: list[dict[str, Any]]) -> RunFolder:
        identity = setup.identity(None, _mode(args))
        identity["board"] = {"boards": [
            BoardIdentity.from_record(b["identity"] or {}).resume_key(b["port"])
            for b in found], "protocol": args.protocol, "mcu": args.mcu, "baud": args.baud,
            "mode": _mode(args), "program": True}
        folder = _open_folder(args, setup, out, identity)
        print_boards(found)
        job.start_here(folder.resumed)
        return folder

    with progress_display() as progress:
        options = run_options(args, progress=progress, seed=args.seed)
        done = run_on_boards(job, boards, dataclasses.replace(options, progress=None),
                             host=dataclasses.replace(options, history=history),
                             on_boards=opened, tell=note)
    results = boards_fields(job, done.result, done.units, done.boards)
    results["run"] = done.run
    results["trained_config_check"] = setup.trained.to_dict()
    paths = write_outputs(results, out, figure=not args.no_figure)
    assert setup.folder is not None
    setup.folder.complete()
    return results, paths


def _on_group(args: argparse.Namespace, setup: _Setup, ports: list[str]
              ) -> tuple[dict[str, Any], dict[str, str]]:
    """The comparison over a chip group (:func:`snan_hil.lab.group_run.run_group_job`):
    every set's share programmed into each chip, every launch's windows on the chip of its
    input neuron; each chip's history records its pulses and the run. (results, files)."""
    outs = Outputs({"--weights": args.weights, "--config": args.config}, force=args.force)
    plans = group_plans(args, ports, outs, updates_layout=True,
                        inputs={"--weights": args.weights, "--config": args.config})
    out = check_out(outs, args.out, NAME, resume=args.resume,
                    files=compare_files(setup.sets if setup.sets is not None
                                        else list(range(setup.n_used)), programming=True,
                                        figure=not args.no_figure, chips=len(ports)))
    job = CompareJob(CompareRequest(
        args.weights, setup.hil, sets=tuple(setup.sets) if setup.sets is not None else None,
        launches=args.launches, seed=args.seed, scenarios=setup.scen, mode="on_board",
        program=True, report_dir=out / "programming", conversions=args.conversions))
    if args.resume:                     # a damaged snapshot: one line, no chip opened
        for plan in plans:
            check_snapshots(out, plan.snapshots)

    def folder(first: BoardSession) -> RunFolder:
        identity = setup.identity(None, "on_board")
        identity["board"] = {"group": ports, "protocol": args.protocol, "mcu": args.mcu,
                             "baud": args.baud, "mode": "on_board", "program": True,
                             **({"conversions": args.conversions}
                                if args.conversions is not None else {})}
        return _open_folder(args, setup, out, identity)
    with progress_display(enabled=not args.json) as show:
        done = run_group_job(job, plans, run_options(args, progress=show, seed=args.seed,
                                                     folder_of=folder))
    results = {**done.result, "run": done.run_block(),
               "trained_config_check": setup.trained.to_dict()}
    paths = write_outputs(results, out, figure=not args.no_figure)
    assert setup.folder is not None
    setup.folder.complete()
    return results, paths


def _history(args: argparse.Namespace, session: BoardSession | None) -> Path | None:
    """Where the run is recorded: the board's history database (hardware scenarios), else
    (software only) ``--history`` or the user's runs database; None with ``--record off``."""
    if not recording(args):
        return None
    if session is not None:
        return session.files.history
    return Path(args.history).expanduser() if args.history else runs_database()


def run_summary(results: dict[str, Any]) -> dict[str, Any]:
    """The RunStop's ``summary`` (:func:`~snan_hil.host.hil.compare.compare_summary`)."""
    return compare_summary(results)


def _report(args: argparse.Namespace, results: dict[str, Any], paths: dict[str, str]) -> int:
    """Print the results (``--json``: the summary as JSON)."""
    if args.json:
        print(json.dumps({k: results.get(k) for k in ("scenarios", "acceptance", "sets",
                                                      "launches", "seed", "wall_s", "run")}
                         | {"files": paths,
                            "speed_energy": results["speed_energy"]["rows"]}))
    else:
        print_results(results, paths)
    print_verdicts(NAME, results, json_mode=args.json)
    return 0


def _check_chip_holds(args: argparse.Namespace, session: BoardSession,
                      sets: list[int] | None) -> None:
    """Without programming: the chip's own layout holding the set, or one line (before the
    run's folder is opened)."""
    layout = load_session_layout(session)
    k = sets[0] if sets else 0
    w, meta = load_weight_set(args.weights, k)
    check_layout(layout, w, tuple(meta["grid"]), port=session.port,
                 weights_path=args.weights, set_index=k, board_options=session.options)


SHORT_LABELS = {"sw_noastro": "software", "sw_astro": "sw + astro", "hw_noastro": "memristor",
                "hw_astro": "memr. + astro"}


def print_results(results: dict[str, Any], paths: dict[str, str] | None = None) -> None:
    """The comparison table, the acceptance checks and the speed/energy table."""
    scen = results["scenarios"]
    per = {(r["scenario"], r["set"]): r for r in results["per_set"]}
    t = Table(title=f"{results['grid'][0]}x{results['grid'][1]} field, cell {results['start']} -> "
                    f"{results['goal']}: median path length of the successful launches "
                    f"({results['launches']} per set; step limit {results['step_limit']})")
    t.add_column("weight set", justify="right")
    for s in scen:
        t.add_column(SHORT_LABELS[s], justify="right")
    fmt = lambda v: "-" if v is None else f"{v:g}"  # noqa: E731
    for k in results["sets"]:
        t.add_row(str(k), *[fmt(per[(s, k)]["median_steps"]) + (
            "" if per[(s, k)]["success_rate"] == 1.0
            else f" ({100 * per[(s, k)]['success_rate']:.0f}%)") for s in scen])
    t.add_section()
    t.add_row("all sets", *[fmt(v["median_steps"]) for v in scen.values()], style="bold")
    t.add_row("  95 % CI", *[format_interval(v.get("median_steps_ci")) for v in scen.values()])
    t.add_row("paper", *["-" if v.get("paper_median_steps") is None else
                         f"{v['paper_median_steps']:g} (inside CI: "
                         f"{inside_text(v.get('paper_inside'))})" for v in scen.values()])
    t.add_row("incl. failed", *[fmt(v["median_steps_all"]) for v in scen.values()])
    t.add_row("success", *[f"{100 * v['success_rate']:.0f} %" for v in scen.values()])
    t.add_row("  95 % CI", *[format_interval(v.get("success_rate_ci"), percent=True, digits=0)
                             for v in scen.values()])
    t.add_row("decisions/s", *["-" if v.get("decisions_per_s") is None
                               else f"{v['decisions_per_s']:,.0f}" for v in scen.values()])
    console.print(t)
    console.print("in brackets: success rate of a set below 100 %; incl. failed: median of all "
                  "launches, a failed launch counted at the step limit; 95 % intervals: "
                  f"{METHOD_TEXT}", highlight=False)
    acc = results["acceptance"]
    yes = lambda v: "-" if v is None else ("yes" if v else "NO")  # noqa: E731
    pct = lambda v: "-" if v is None else f"{100 * v:+.0f} %"  # noqa: E731
    for suffix, what in (("", "successful launches"), ("_all", "all launches, failed at "
                                                       "the limit")):
        console.print(f"median of {what}: astrocytes shorten it in software "
                      f"{yes(acc['sw_astro_shortens' + suffix])} (beyond the 95 % intervals: "
                      f"{yes(acc.get('sw_astro_shortens_ci' + suffix))}), hardware "
                      f"{yes(acc['hw_astro_shortens' + suffix])} (beyond: "
                      f"{yes(acc.get('hw_astro_shortens_ci' + suffix))}); hardware vs software: "
                      f"no astro {pct(acc['hw_vs_sw_noastro' + suffix])} (within 20 %: "
                      f"{yes(acc['hw_within_20pct_noastro' + suffix])}), astro "
                      f"{pct(acc['hw_vs_sw_astro' + suffix])} (within 20 %: "
                      f"{yes(acc['hw_within_20pct_astro' + suffix])})", highlight=False)
    prog = results.get("programming") or {}
    if prog:
        bad = {k: v for k, v in prog.items() if not v.get("all_ok")}
        pulses = sum(v.get("pulses_total") or 0 for v in prog.values())
        console.print(f"programming: {len(prog)} set(s), {pulses} pulses in all"
                      + (f"; cells outside their window in set(s) {', '.join(bad)}" if bad
                         else "; every cell inside its window"))
    se = Table(title="speed and energy per decision (paper Fig. 10D)")
    for col in ("#", "implementation", "time", "spikes", "per spike", "energy", "dec/us/mm2",
                "speed", "energy"):
        se.add_column(col, justify="left" if col == "implementation" else "right")
    rows = results["speed_energy"]["rows"]
    for i, r in enumerate(rows, 1):
        gain = r["energy_gain_vs_cpu"]
        spikes, per = r.get("spikes_per_decision"), r.get("time_per_spike_us")
        se.add_row(str(i), r["implementation"], format_si(r["time_per_decision_us"] * 1e-6, "s"),
                   "-" if spikes is None else f"{spikes:.0f}",
                   "-" if per is None else format_si(per * 1e-6, "s"),
                   format_si(r["energy_per_decision_j"], "J"),
                   "-" if r["norm_speed_per_us_mm2"] is None
                   else f"{r['norm_speed_per_us_mm2']:.3g}",
                   "-" if r["speed_vs_cpu"] is None else f"{r['speed_vs_cpu']:.3g}x",
                   "-" if gain is None else (f"1/{gain:,.0f}" if gain >= 10
                                             else f"1/{gain:.2g}"))
    console.print(se)
    console.print("speed: normalised speed / CPU's (paper method); energy: energy / CPU's",
                  highlight=False)
    for i, r in enumerate(rows, 1):
        console.print(f"  {i}. [{r['source']}] {r['method']}", highlight=False, markup=False)
    console.print(f"wall time {results['wall_s']:.1f} s")
    if paths:
        console.print("written: " + ", ".join(paths.values()))
