"""``compare --boards PORT,PORT,...`` / ``--dask tcp://host:8786``: one comparison over several
boards (:mod:`snan_hil.lab.boards`; docs/multiboard.md).

Everything the user gave is checked before a worker starts (ports, options, outputs, a reused
``--out``); then the boards are opened by their workers (a board that does not open: one line,
exit 2, nothing run), the sets run as units on the boards and the merged results are written
as a one-board run writes them, with ``units`` (which board ran which set) and ``boards``
(every board's snapshot).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from snan_hil.board.identity import BoardIdentity
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.files.outputs import Outputs
from snan_hil.host.checkpoint import check_out, open_run
from snan_hil.host.hil.config import HilConfig
from snan_hil.lab.opener import FileUse
from snan_hil.records.control import RunControl
from snan_hil.records.history import check_history_file
from snan_hil.tools import cli
from snan_hil.tools.commands._history import open_recorder, recording
from snan_hil.tools.commands._run import (CONTROL_LINES, event_sink, metadata_from_args,
                                          progress_to, run_block, runs_database)
from snan_hil.tools.console import err_console, progress_display
from snan_hil.tools.output_kinds import compare_files

if TYPE_CHECKING:           # distributed and the compare are imported when several boards run
    from snan_hil.lab.boards import LinkOptions

__all__ = ["add_board_options", "multi_board", "run_on_boards", "add_every_board_options",
           "every_board", "board_argv", "board_output", "command_unit",
           "add_learn_board_options", "LearnBoards", "learn_boards"]


def add_board_options(parser: argparse.ArgumentParser) -> None:
    """``--boards``, ``--dask``, ``--reassign``."""
    parser.add_argument("--boards", default=None, metavar="PORT,PORT,...",
                        help="run the sets over several boards on this machine, one worker "
                             "process per board (the sets balanced over the boards by their "
                             "predicted board time); e.g. "
                             "'emu://?state=a.npz,emu://?state=b.npz' (docs/multiboard.md; "
                             "default: the one board of --port)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run the sets over the boards held by the workers of this Dask "
                             "scheduler (tcp://host:8786; one worker per board, started with "
                             "SNAN_HIL_BOARD=PORT and --resources board=1,board-<i>=1; "
                             "default: no scheduler, the boards of --boards or --port)")
    parser.add_argument("--reassign", action="store_true",
                        help="with --boards/--dask: move the sets of a board lost mid-run to "
                             "the other boards (programmed there first); without it the run "
                             "stops once the other boards are done (continue with --resume)")


def multi_board(args: argparse.Namespace) -> bool:
    """Whether the options ask for several boards (UserError for a combination that
    cannot be)."""
    boards, dask = getattr(args, "boards", None), getattr(args, "dask", None)
    if boards is None and dask is None:
        if getattr(args, "reassign", False):
            raise UserError("--reassign moves sets between boards; give --boards or --dask")
        return False
    if boards is not None and dask is not None:
        raise UserError("give --boards (workers on this machine) or --dask (a scheduler's "
                        "workers), not both")
    if args.port is not None:
        raise UserError("--port names one board; with --boards/--dask each worker holds its "
                        "own (leave --port out)")
    if args.layout is not None:
        raise UserError("--layout names one board's layout; with --boards/--dask each board "
                        "uses its own (leave --layout out)")
    if args.no_program:
        raise UserError("--no-program works with one board (the chip holds one set); "
                        "leave it out with --boards/--dask")
    return True


def run_on_boards(args: argparse.Namespace, *, name: str, meta: dict[str, Any],
                  sets: list[int] | None, scen: tuple[str, ...], hil: HilConfig,
                  n_used: int, trained: Any, hw_mode: str | None,
                  run_identity: Callable[..., dict[str, Any]],
                  summary: Callable[[dict[str, Any]], dict[str, Any]]
                  ) -> tuple[dict[str, Any], dict[str, str]]:
    """The comparison over several boards: (results, written files). UserError (one line,
    before any set runs) for bad ports, outputs, a scheduler that does not answer, a board
    that does not open. The run is recorded (kind ``hil``: metadata, the launches stream of
    every set as its board ends it, every board in the config and the stop's summary
    (``summary(results)`` + ``boards``) in ``--history``, else the user's runs database;
    each board's history records its programming with the same metadata; ``snan-hil watch
    --history DB`` follows it and its pause / stop reach every board)."""
    from snan_hil.host.hil.compare import CompareRequest, run_compare, write_outputs
    from snan_hil.lab.boards import (BoardPlugin, BoardPool, LinkOptions, RunLink, check_ports,
                                     connect_scheduler, local_boards)
    if not any(s.startswith("hw_") for s in scen):
        raise UserError("--boards/--dask spread the hardware scenarios; --scenarios has none "
                        "(give hw_noastro or hw_astro, or leave --boards out)")
    link = LinkOptions(protocol=args.protocol, baud=args.baud, timeout=args.timeout,
                       mcu=args.mcu, max_write_v=args.max_write_v)
    ports = check_ports(args.boards.split(","), link) if args.boards is not None else None
    outs = Outputs({"--weights": args.weights, "--config": args.config}, force=args.force)
    out = check_out(outs, args.out, name, resume=args.resume,
                    files=compare_files(sets if sets is not None else list(range(n_used)),
                                        programming=True, figure=not args.no_figure))
    level = (args.record if args.record != "off" else None) if recording(args) else None
    # the run itself (metadata, the launches stream, every board's snapshot, the control
    # channel of snan-hil watch): --history, else the user's runs database
    history = None
    if recording(args):
        history = check_history_file(Path(args.history).expanduser()) if args.history \
            else runs_database()
    metadata_from_args(args)                    # a bad --sample ...: one line, before work
    plugin = BoardPlugin(FileUse(record=level is not None, updates_layout=True), link,
                         force=args.force, cwd=os.getcwd() if ports is not None else None)
    cluster = local_boards(ports) if ports is not None else connect_scheduler(args.dask)
    with cluster as client:
        pool = BoardPool(client, reassign=args.reassign, level=level, seed=args.seed)
        boards = pool.install(plugin, expect=len(ports) if ports is not None else None)
        identity = run_identity(args, meta, sets, scen, hil, None, hw_mode)
        identity["board"] = {"boards": [
            BoardIdentity.from_record(b["identity"] or {}).resume_key(b["port"])
            for b in boards], "protocol": args.protocol, "mcu": args.mcu, "baud": args.baud,
            "mode": hw_mode, "program": True}
        run_folder = open_run(out, name, identity, resume=args.resume)
        # each board's chip before each set, in the checkpoint: on one machine the workers
        # share it; a scheduler's workers reach it as they reach --out/programming
        pool.boundary = str(run_folder.path("boards").resolve())
        for line in trained.notes(args.weights):
            err_console.print(line, markup=False, highlight=False, soft_wrap=True)
        if run_folder.resumed:
            err_console.print(f"resuming the run in {out}", highlight=False, soft_wrap=True)
        err_console.print(f"{len(boards)} boards: " + ", ".join(
            f"{b['board']}={b['port']}" for b in boards), highlight=False, soft_wrap=True)
        # absolute: a scheduler's workers need not share this folder as their working one
        request = CompareRequest(str(Path(args.weights).resolve()), hil,
                                 sets=tuple(sets) if sets is not None else None,
                                 launches=args.launches, seed=args.seed, scenarios=scen,
                                 mode=hw_mode, program=True,
                                 report_dir=out.resolve() / "programming",
                                 conversions=getattr(args, "conversions", None))
        config = {"weights": request.weights_path,
                  "sets": None if request.sets is None else list(request.sets),
                  "launches": request.launches, "scenarios": list(request.scenarios),
                  "mode": request.mode, "program": request.program,
                  "conversions": request.conversions,
                  "boards": [{"board": b["board"], "port": b["port"],
                              "board_id": (b["identity"] or {}).get("board_id")}
                             for b in boards]}
        with progress_display() as progress, \
                open_recorder(args, history, "hil", None, seed=args.seed,
                              config=config) as rec:
            if rec.path is not None and rec.active:
                err_console.print(f"recorded in {rec.path} (follow it: snan-hil watch "
                                  f"--history {rec.path})", highlight=False, soft_wrap=True)
                control = RunControl(rec.path, rec.uid, db=rec.db,
                                     on_action=lambda action: _tell(rec, action))
                rec.control = control           # closed with the run
                pool.stop_requested = control.stop_requested
            m = rec.metadata
            pool.run = RunLink(history=str(rec.path) if rec.path is not None else None,
                               uid=rec.uid, metadata={"sample": m.sample, "operator": m.operator,
                                                      "note": m.note, "tags": tuple(m.tags)})
            results = run_compare(request, progress=progress_to(progress, rec),
                                  checkpoint=run_folder, units=pool,
                                  launches=event_sink(rec))
            rec.finish("complete", {**summary(results), "boards": [
                {"board": b.get("board"), "port": b.get("port"), "lost": b.get("lost"),
                 "board_id": (b.get("identity") or {}).get("board_id")}
                for b in results.get("boards") or []]})
        results["run"] = run_block(rec, args)
    results["trained_config_check"] = trained.to_dict()
    paths = write_outputs(results, out, figure=not args.no_figure)
    run_folder.complete()
    return results, paths


def _tell(rec: Any, action: str) -> None:
    """A control action (pause, resume, stop from snan-hil watch) into the run's stream."""
    if not rec.publisher.stopped:
        rec.publisher.event("control", {"action": action, "detail": "snan-hil watch"})
        rec.flush()
    if action in CONTROL_LINES:
        err_console.print(CONTROL_LINES[action], markup=False, highlight=False)


# -- the lab-bench batch jobs: the same job on every board's chip ----------------------------

def add_every_board_options(parser: argparse.ArgumentParser) -> None:
    """``--boards`` / ``--dask`` of a lab-bench batch job (``cells test``, ``plan run``,
    ``plan repeat``): the same job on every board's own chip, one unit per board."""
    parser.add_argument("--boards", default=None, metavar="PORT,PORT,...",
                        help="run the same job on each of these boards' own chips, one worker "
                             "process per board; each board's outputs get '.board-<i>' before "
                             "their suffix (docs/multiboard.md; default: the one board of "
                             "--port)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run the same job on the chip of every board the workers of this "
                             "Dask scheduler hold (tcp://host:8786; default: no scheduler)")


def board_output(path: str, board: int) -> str:
    """``good.csv`` -> ``good.board-<i>.csv`` (a board's own copy of an output file)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}.board-{board}{p.suffix}"))


def board_argv(argv: list[str], port: str, board: int, outputs: tuple[str, ...]) -> list[str]:
    """The job's command line for one board: ``--boards``/``--dask`` left out, ``--port PORT``
    added, each output file of ``outputs`` (options taking a file) made the board's own."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        name, eq, value = a.partition("=")
        if name in ("--boards", "--dask"):
            if not eq:
                next(it, None)
            continue
        if name in outputs:
            value = value if eq else next(it, "")
            out += [name, board_output(value, board)]
            continue
        out.append(a)
    return [*out, "--port", port]


def command_unit(argv: list[str], outputs: tuple[str, ...]) -> dict[str, Any]:
    """The task of one board's share of a batch job (on the worker holding it): the command
    line run with the worker's port (:func:`board_argv`), its exit code and what it
    printed."""
    from snan_hil.lab.boards import _plugin         # distributed: only with --boards/--dask
    plugin = _plugin()
    if plugin.port is None or plugin.index is None:
        raise RuntimeError(plugin.error or "this worker holds no board")
    line = board_argv(argv, plugin.port, plugin.index, outputs)
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = cli.main(line)
    return {"board": plugin.index, "port": plugin.port, "worker": plugin.worker_address,
            "argv": line, "exit": int(code),
            "stdout": stdout.getvalue(), "stderr": stderr.getvalue()}


def every_board(args: argparse.Namespace, *, outputs: tuple[str, ...] = (),
                use: FileUse | None = None) -> int | None:
    """With ``--boards``/``--dask``: the job of ``args`` run on every board's own chip, one
    unit per board (each board's history records its own run, each its own output files);
    prints each board's output under a header naming the board; the exit code (0, or the
    first board's that failed; a user mistake: its one line, 2). None without them (one
    board: the caller carries on)."""
    boards, dask = getattr(args, "boards", None), getattr(args, "dask", None)
    if boards is None and dask is None:
        return None
    from snan_hil.lab.boards import (BoardPlugin, BoardPool, LinkOptions, check_ports,
                                     connect_scheduler, local_boards)
    if boards is not None and dask is not None:
        raise UserError("give --boards (workers on this machine) or --dask (a scheduler's "
                        "workers), not both")
    if args.port is not None:
        raise UserError("--port names one board; with --boards/--dask each worker holds its "
                        "own (leave --port out)")
    if getattr(args, "layout", None) is not None:
        raise UserError("--layout names one board's layout; with --boards/--dask each board "
                        "uses its own (leave --layout out)")
    if getattr(args, "dry_run", False):
        raise UserError("--dry-run opens no board; leave --boards/--dask out")
    link = LinkOptions(protocol=args.protocol, baud=args.baud, timeout=args.timeout,
                       mcu=getattr(args, "mcu", None),
                       max_write_v=getattr(args, "max_write_v", None))
    ports = check_ports(boards.split(","), link) if boards is not None else None
    argv = list(getattr(args, "_argv", []))
    plugin = BoardPlugin(use or FileUse(record=True), link, force=args.force,
                         cwd=os.getcwd() if ports is not None else None, probe=False)
    from distributed import wait                # the dask extra

    cluster = local_boards(ports) if ports is not None else connect_scheduler(str(dask))
    with cluster as client:
        pool = BoardPool(client)
        found = pool.install(plugin, expect=len(ports) if ports is not None else None)
        futures = [client.submit(command_unit, argv, outputs, pure=False,
                                 resources={f"board-{b['board']}": 1},
                                 key=f"snan-hil-job-board-{b['board']}-{uuid.uuid4().hex[:8]}")
                   for b in found]
        wait(futures)
        for b, fut in zip(found, futures):
            if fut.status != "finished":    # a worker killed, a port gone: the board's job
                from snan_hil.lab.boards import _reason
                raise BoardLinkError(f"board {b['board']} ({b['port']}) was lost: "
                                     f"{_reason(fut)}; the other boards' jobs finished; run it "
                                     "again on that board (its history holds what was done)")
        done = [f.result() for f in futures]
    mistakes = [d for d in done if d["exit"] == 2]
    if mistakes:                        # one line: the first board's, its own prefix left out
        first = mistakes[0]
        text = (first["stderr"].strip().splitlines() or ["exit 2"])[-1]
        raise UserError(f"board {first['board']} ({first['port']}): "
                        + text.split(": error: ", 1)[-1])
    code = 0
    for d in done:
        err_console.print(f"board {d['board']} ({d['port']}, worker {d['worker']}): exit "
                          f"{d['exit']}", highlight=False, soft_wrap=True, markup=False)
        if d["stdout"]:
            print(d["stdout"], end="" if d["stdout"].endswith("\n") else "\n", flush=True)
        if d["stderr"]:
            err_console.print(d["stderr"].rstrip(), highlight=False, soft_wrap=True,
                              markup=False)
        code = code or d["exit"]
    return code


# -- learn: one learning session per unit ------------------------------------------------------

def add_learn_board_options(parser: argparse.ArgumentParser) -> None:
    """``learn --boards`` / ``--dask``: the chip arm's sessions spread over boards."""
    parser.add_argument("--boards", default=None, metavar="PORT,PORT,...",
                        help="run the chip arm's sessions over several boards on this machine, "
                             "one worker process per board (session k on board k mod B, each "
                             "on its own chip); needs --model (docs/multiboard.md; default: "
                             "the one board of --port)")
    parser.add_argument("--dask", default=None, metavar="ADDRESS",
                        help="run the chip arm's sessions over the boards held by the workers "
                             "of this Dask scheduler (tcp://host:8786; default: no scheduler)")
    parser.add_argument("--reassign", action="store_true",
                        help="with --boards/--dask: move the unfinished sessions of a board "
                             "lost mid-run to a board still held, where each goes on from its "
                             "last committed cycle after that chip is reprogrammed to the "
                             "session's weights (the lost board's pulses stay counted on it); "
                             "without it the run stops once the other boards are done "
                             "(continue with --resume)")


@dataclass
class LearnBoards:
    """The boards of a ``learn --boards/--dask`` run: checked before any work
    (:func:`learn_boards`); :meth:`connected` reaches them (the scheduler answers, every
    board opens: one line at once otherwise) and gives the ``ChipUnits`` that runs the
    sessions on them."""

    ports: list[str] | None
    dask: str | None
    link: LinkOptions
    level: str | None
    force: bool
    reassign: bool = False
    units: dict[str, Any] = field(default_factory=dict)
    boards: list[dict[str, Any]] = field(default_factory=list)

    def identity(self) -> dict[str, Any]:
        """What a resumed run must match: the ports (or the scheduler) and the link."""
        return {"boards": self.ports, "dask": self.dask, "protocol": self.link.protocol,
                "mcu": self.link.mcu}

    @contextmanager
    def connected(self, seed: int) -> Iterator[Callable[..., Any]]:
        """The boards reached (the cluster started or the scheduler connected, every board
        opened by its worker) for the time of the ``with``: yields
        :meth:`~snan_hil.lab.boards.BoardPool.run_sessions` (sessions seeded from
        ``seed``)."""
        from snan_hil.lab.boards import BoardPlugin, BoardPool, connect_scheduler, local_boards
        plugin = BoardPlugin(FileUse(record=self.level is not None, updates_layout=True),
                             self.link, force=self.force,
                             cwd=os.getcwd() if self.ports is not None else None,
                             command="snan-hil learn")
        cluster = local_boards(self.ports) if self.ports is not None else \
            connect_scheduler(str(self.dask))
        with cluster as client:
            pool = BoardPool(client, level=self.level, seed=seed, reassign=self.reassign)
            self.boards = pool.install(plugin, expect=len(self.ports) if self.ports else None)
            err_console.print(f"{len(self.boards)} boards: " + ", ".join(
                f"{b['board']}={b['port']}" for b in self.boards), highlight=False,
                soft_wrap=True)
            yield pool.run_sessions


def learn_boards(args: argparse.Namespace, chip: bool) -> LearnBoards | None:
    """``learn``'s --boards/--dask checked (UserError, one line): None without them."""
    boards, dask = getattr(args, "boards", None), getattr(args, "dask", None)
    if boards is None and dask is None:
        if getattr(args, "reassign", False):
            raise UserError("--reassign moves sessions between boards; give --boards or "
                            "--dask (one board: continue a lost run with --resume)")
        return None
    from snan_hil.lab.boards import LinkOptions, check_ports
    if boards is not None and dask is not None:
        raise UserError("give --boards (workers on this machine) or --dask (a scheduler's "
                        "workers), not both")
    if not chip:
        raise UserError("--boards/--dask spread the chip arm's sessions; --arms has no chip "
                        "(add it, or leave --boards out)")
    if args.port is not None:
        raise UserError("--port names one board; with --boards/--dask each worker holds its "
                        "own (leave --port out)")
    if args.layout is not None:
        raise UserError("--layout names one board's layout; with --boards/--dask each board "
                        "uses its own (leave --layout out)")
    if not args.model:
        raise UserError("--boards/--dask need the device model as a file (--model FILE, "
                        "'snan-hil characterize --model FILE'): each board's history is on "
                        "its worker")
    link = LinkOptions(protocol=args.protocol, baud=args.baud, timeout=args.timeout,
                       mcu=args.mcu, max_write_v=getattr(args, "max_write_v", None))
    ports = check_ports(boards.split(","), link) if boards is not None else None
    level = (args.record if args.record != "off" else None) if recording(args) else None
    return LearnBoards(ports, dask, link, level, bool(args.force),
                       reassign=bool(getattr(args, "reassign", False)))
