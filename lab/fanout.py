"""A job over several boards: the one scheduling loop of every job (``--boards`` / ``--dask``).

The boards are held by Dask workers (:mod:`snan_hil.lab.boards`: one worker a board, its
:class:`~snan_hil.lab.boards.BoardPlugin`). The job's units are placed by **group** (the
units of a group run in order on one board: a weight set of a comparison, a learning
session): each group is one task, submitted to its board's worker and chained after that
board's previous group. The worker runs :func:`run_group` — the same unit loop as a run on one
board (:func:`snan_hil.lab.runner.run_units`: the bench, the journal, the board's own history
run, the checkpoint's units) — and knows no job type. A job without groups (a cell test, a
pulse plan) is **replicated**: the whole job on every board's own chip, a result per board.

Placement (:func:`~snan_hil.lab.boards.assign`): a group the run's checkpoint places already
(``groups.json``: it ran or moved there in an earlier run) goes back to that board; the
others by position, or balanced by the job's predicted cost per group (``group_cost()``,
longest first) when there are more groups than boards. A board lost mid-run (its task failed
without a user mistake, or no worker held it for ``lost_after_s``): the finished groups are
kept; with ``reassign`` its groups move to the boards still held (recorded in ``groups.json``,
so a resumed run keeps them there; the job's unit sees ``ctx.board`` and handles the move:
a learning session reprograms its new chip), else the run stops once the other boards are done
(``--resume`` goes on). A user mistake in a group stops the run in one line, the board kept.
A replicated job's boards all end their runs; then the first board's mistake is the one line,
or a lost board is named (the other boards' runs are kept in their histories). The host writes
and prints each board's outputs from its :class:`BoardResult` (records, port, identity, session
snapshot, run block: :func:`run_group` returns them, none of them job-specific).
A stop from ``snan-hil watch`` in the run's control channel reaches every board's worker before
its next board request; the run raises :class:`~snan_hil.records.control.StopRequested`.

The run itself is recorded once on the host side (the caller's recorder, e.g. the user's runs
database): the events each board's units emitted (a comparison's ``launches`` stream) are
re-emitted there as each group comes back, so ``snan-hil watch --history DB`` follows the whole
run; each board's own history records the pulses its chip took.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from snan_hil.calibration.job import BoardJob
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.common.progress import track
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.host.checkpoint import RunFolder
from snan_hil.lab.boards import (_RESOURCE, BoardPlugin, RunLink, UnitStopped, _describe_worker,
                                 _plugin, _reason, _stopped, _task_states, _user_error, assign,
                                 board_resource, connect_scheduler, install_boards,
                                 local_boards)
from snan_hil.lab.runner import HostRun, RunOptions, _open_run, run_units
from snan_hil.records.control import StopRequested
from snan_hil.records.documents import DocumentCollector, RunMetadata

__all__ = ["GroupTask", "run_group", "Fanout", "BoardResult", "BoardSet", "BoardsRun",
           "run_on_boards", "PLACEMENT_FILE"]

log = logging.getLogger(__name__)

PLACEMENT_FILE = "groups.json"
"""The checkpoint's record of which board holds each group (``{group: board}``)."""


@dataclass(frozen=True)
class GroupTask:
    """What a worker needs besides the job: the group (None: the whole job), the run's
    control channel and metadata (:class:`~snan_hil.lab.boards.RunLink`), the history record
    level on the board (None: not recorded), the command line, the seed, and the run's
    checkpoint folder (its path: the workers reach it on this machine, or as they reach
    ``--out``)."""

    group: str | None
    link: RunLink = field(default_factory=RunLink)
    level: str | None = "pulses"
    command: str = "snan-hil"
    seed: int | None = None
    folder: RunFolder | None = None


def run_group(job: BoardJob[Any, Any], task: GroupTask, after: Any = None) -> dict[str, Any]:
    """The task of one group on the worker holding the board: a fresh connection to the board
    (on an emulated chip a fresh boot), the board's own history run of the group, the unit
    loop. Returns ``{"board", "records" (by unit key), "events" ([stream, data] the units
    emitted), "unit" (board number, port, board id, worker), "run" (the board's run as the
    host reports it, none of it job-specific: ``identity`` (board id, firmware version),
    ``session`` (:meth:`~snan_hil.board.session.BoardSession.snapshot`), ``block`` (uid,
    metadata, history run id), ``documents`` (the run's identity from its own document
    stream, exit status included))}``. ``after``: the board's
    previous task (orders the board's groups only). A stop in the run's control channel raises
    :class:`~snan_hil.lab.boards.UnitStopped`."""
    plugin = _plugin()
    events: list[tuple[str, dict[str, Any]]] = []
    collector = _RunEnds()
    link = task.link
    options = RunOptions(record=task.level or "off",
                         metadata=RunMetadata(**link.metadata), command=task.command,
                         folder=task.folder, seed=task.seed, warn=log.warning,
                         control=(link.history, link.uid) if link.history and link.uid
                         else None, subscribers=(collector,))
    restartable = bool(getattr(job, "restartable", False))
    with _planned_unseen(plugin) if restartable else contextlib.nullcontext():
        session = plugin.open()
        try:
            run = _open_run(job, session, options, board=plugin.index)
        except BaseException:
            session.close()
            raise
        if restartable and session.reopen_with is not None:
            session.close()                   # every unit on its own connection, as on one
            run.fresh = True                  # board (lab.runner.run_job)
    with session:
        board_emit = run.emit

        def emit(stream: str, data: dict[str, Any]) -> None:
            events.append((stream, data))
            board_emit(stream, data)
        run.emit = emit
        records: dict[str, dict[str, Any]] = {}
        try:
            units = [u for u in run.units if task.group is None or u.group == task.group]
            run_units(job, units, run, options, board=plugin.index, records=records)
        except StopRequested as stop:
            run.finish("interrupted", reason=str(stop))
            raise UnitStopped(f"{_what(task)} on board {plugin.index}: {stop}") from None
        except BaseException as exc:
            run.finish("failed", reason=f"{type(exc).__name__}: {exc}")
            raise
        run.finish("complete", {"group": task.group, "units": len(records)})
        unit = {"board": plugin.index, "port": plugin.port,
                "board_id": session.identity.board_id, "worker": plugin.worker_address}
        board_run = {"identity": session.identity.to_dict(), "session": session.snapshot(),
                     "block": {**run.rec.metadata.to_dict(), "history_run_id": run.rec.run_id},
                     "documents": collector.run_block()}
    return {"board": plugin.index, "records": records, "events": events, "unit": unit,
            "run": board_run}


class _RunEnds(DocumentCollector):
    """The board run's start and stop documents only (its run block), not its events."""

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        if name in ("start", "stop"):
            super().__call__(name, doc)


@contextlib.contextmanager
def _planned_unseen(plugin: BoardPlugin) -> Iterator[None]:
    """An emulated chip put back as it was once a restartable job's group is planned (its
    plan's session closed): the chip's boot number seeds the boot's ADC noise, so a boot more
    than a one-board run makes would change every read after it. On one board the run's one
    plan session is the boot before the units'; here the worker's first look at its board
    (:class:`~snan_hil.lab.boards.BoardPlugin`'s probe) is that boot, and each group's own
    plan leaves the chip as it found it. Nothing for a real chip (it has no snapshots)."""
    snapshots = plugin.snapshots()
    if snapshots is None:
        yield
        return
    with tempfile.TemporaryDirectory(prefix="snan-hil-plan-") as tmp:
        saved = Path(tmp) / "chip"
        snapshots.save(saved)
        yield
        snapshots.restore(saved)


def _what(task: GroupTask) -> str:
    return "the job" if task.group is None else f"group {task.group}"


@dataclass
class BoardResult:
    """One board's share of a replicated job: its number, ``unit`` (number, port, board id,
    worker), the records of its units (the job's result on that board:
    ``job.result(records, "complete")``), and ``run``: the board's run as :func:`run_group`
    returns it (identity, session snapshot, run block, documents' run block) -- what the
    host needs to write and print that board's outputs without its session."""

    board: int
    unit: dict[str, Any]
    records: dict[str, dict[str, Any]]
    run: dict[str, Any] = field(default_factory=dict)

    @property
    def port(self) -> str:
        return str(self.unit.get("port"))


@dataclass
class _Board:
    index: int
    info: dict[str, Any]
    last: Any = None                    # the future of its last submitted task
    lost: str | None = None
    gone_since: float | None = None


@dataclass
class Fanout:
    """The scheduling loop of a job over the boards of ``client`` (their plugins installed:
    ``boards`` are their descriptions, :meth:`snan_hil.lab.boards.BoardPlugin.describe`).
    ``reassign``: a lost board's groups move to the others; ``lost_after_s``: how long a
    board may have no worker before it counts as lost; ``stop_requested()``: the run's own look
    at its control channel (a stop cancels the groups not started and ends the run with
    :class:`StopRequested`); ``emit(stream, data)``: the run's document stream on the host
    (each group's events re-emitted as it comes back); ``task``: the worker function (tests
    replace it)."""

    client: Any
    boards: list[dict[str, Any]]
    reassign: bool = False
    lost_after_s: float = 60.0
    poll_s: float = 1.0
    stop_requested: Callable[[], bool] | None = None
    emit: Callable[[str, dict[str, Any]], None] | None = None
    task: Callable[..., dict[str, Any]] = run_group
    moved: dict[str, int] = field(default_factory=dict)
    _boards: list[_Board] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._boards = [_Board(int(b["board"]), b) for b in self.boards]

    # -- placement ---------------------------------------------------------------------------
    def place(self, groups: Sequence[str], cost: Mapping[str, float] | None,
              folder: RunFolder | None) -> dict[str, int]:
        """Group -> board (module doc)."""
        n = len(self._boards)
        where = {g: b for g, b in _placed(folder).items() if g in groups and 0 <= b < n}
        order = list(groups)
        index = {g: i for i, g in enumerate(order)}
        fresh = assign([index[g] for g in order], n,
                       None if cost is None else {index[g]: float(cost[g]) for g in order})
        for g in order:
            where.setdefault(g, fresh[index[g]])
        return where

    # -- the loop ----------------------------------------------------------------------------
    def run(self, job: BoardJob[Any, Any], tasks: Sequence[tuple[str | None, int]],
            task: GroupTask, done: Callable[[str | None, dict[str, Any]], None]) -> None:
        """Run each (group, board) of ``tasks`` (group None: the whole job on that board);
        ``done(group, payload)`` for each that comes back, in the order of ``tasks`` among
        those that end together. A user mistake in a group stops the run (UserError naming
        the group and board); in a replicated job (group None) every board's run ends first,
        then the lowest board's mistake is the one line (``board B (PORT): ...``)."""
        from distributed import wait
        from distributed.client import FuturesCancelledError
        running: dict[Any, tuple[int, str | None, int]] = {}
        for i, (g, b) in enumerate(tasks):
            b = self.moved.get(str(g), b) if g is not None else b
            running[self._submit(job, task, g, b)] = (i, g, b)
        stopping = False
        mistakes: dict[int, str] = {}
        while running:
            try:
                finished, _ = wait(list(running), timeout=self.poll_s,
                                   return_when="FIRST_COMPLETED")
            except TimeoutError:
                finished = set(self._watch(running))
            except FuturesCancelledError:       # cancelled by a stop or a lost board
                finished = {f for f in running if f.status in ("cancelled", "finished",
                                                               "error")}
            if not stopping and self.stop_requested is not None and self.stop_requested():
                stopping = True
                self._stop(running)
            for fut in sorted(finished, key=lambda f: running[f][0]):
                i, g, b = running.pop(fut)
                what = "the job" if g is None else _group_name(job, g)
                if fut.status == "finished":
                    payload = fut.result()
                    self._replay(payload)
                    done(g, payload)
                    continue
                if (stopping and fut.status == "cancelled") or _stopped(fut):
                    if not stopping:
                        stopping = True
                        self._stop(running)
                    continue
                mistake = _user_error(fut)
                if mistake is not None and g is None:   # replicated: every board's own run
                    mistakes[b] = mistake               # ends (a refusal sends nothing)
                    continue
                if mistake is not None:     # the input, not the board: stop, board kept
                    self.client.cancel(list(running))
                    raise UserError(f"{what} on board {b}: {mistake}")
                self._lose(b, f"{what} failed: {_reason(fut)}")
                if self.reassign and g is not None:
                    target = self._survivor(job, g)
                    self.moved[str(g)] = target
                    _record_move(task.folder, str(g), target)
                    log.warning("%s moves from board %s to board %s", what, b, target)
                    running[self._submit(job, task, g, target)] = (i, g, target)
        self._end(mistakes, stopping, replicated=all(g is None for g, _b in tasks))

    def _end(self, mistakes: dict[int, str], stopping: bool, *, replicated: bool) -> None:
        """How a run whose tasks all came back ends: the first board's mistake of a
        replicated job, a stop, a board lost without reassign (a replicated job's: the other
        boards' runs finished, that board's is run again on it alone)."""
        if mistakes:                    # the first board's line, whichever ended first
            b = min(mistakes)
            raise UserError(f"board {b} ({self._boards[b].info.get('port')}): {mistakes[b]}")
        if stopping:
            raise StopRequested("stop requested (snan-hil watch)")
        lost = [board for board in self._boards if board.lost is not None]
        if lost and replicated:
            first = lost[0]
            raise BoardLinkError(f"board {first.index} ({first.info.get('port')}) was lost "
                                 f"({first.lost}); the other boards' runs finished and are in "
                                 "their own histories, but no output file was written: run it "
                                 "again on that board (its history holds what was done)")
        if lost and not self.reassign:
            first = lost[0]
            raise BoardLinkError(f"board {first.index} ({first.info.get('port')}) was lost "
                            f"({first.lost}); the finished work is kept: run again with "
                            "--resume when it is back, or add --reassign to move its work to "
                            "the other boards")

    def _replay(self, payload: dict[str, Any]) -> None:
        if self.emit is None:
            return
        for stream, data in payload.get("events", []):
            self.emit(stream, data)

    def _submit(self, job: BoardJob[Any, Any], task: GroupTask, g: str | None, b: int) -> Any:
        board = self._boards[b]
        mine = GroupTask(g, task.link, task.level, task.command, task.seed, task.folder)
        fut = self.client.submit(self.task, job, mine, after=board.last, pure=False,
                                 resources={board_resource(b): 1},
                                 key=f"snan-hil-{job.kind}-{g}-board-{b}-"
                                     f"{uuid.uuid4().hex[:8]}")
        board.last = fut
        return fut

    def _stop(self, running: dict[Any, tuple[int, str | None, int]]) -> None:
        log.warning("stop requested: no further group starts")
        waiting = [f for f in running if f.status == "pending" and not self._started(f)]
        if waiting:
            self.client.cancel(waiting)

    def _started(self, fut: Any) -> bool:
        try:
            states = self.client.run_on_scheduler(_task_states, keys=[fut.key])
        except Exception:                 # noqa: BLE001 - unknown: let it run
            return True
        return states.get(fut.key) in ("processing", "memory", "erred")

    def _survivor(self, job: BoardJob[Any, Any], g: str) -> int:
        alive = [b for b in self._boards if b.lost is None]
        if not alive:
            raise BoardLinkError(f"every board was lost ({_group_name(job, g)} could not be "
                            "moved): " + "; ".join(f"board {b.index}: {b.lost}"
                                                   for b in self._boards)
                            + "; the finished work is kept: run again with --resume")
        k = int(g) if str(g).isdigit() else sum(map(ord, str(g)))
        return alive[k % len(alive)].index

    def _lose(self, b: int, reason: str) -> None:
        board = self._boards[b]
        if board.lost is None:
            board.lost = reason
            board.last = None
            log.warning("board %s (%s) lost: %s", b, board.info.get("port"), reason)

    def _watch(self, running: dict[Any, tuple[int, str | None, int]]) -> list[Any]:
        held: set[str] = set()
        for w in self.client.scheduler_info(n_workers=-1).get("workers", {}).values():
            held.update(r for r in (w.get("resources") or {}) if _RESOURCE.match(r))
        now = time.monotonic()
        stuck: list[Any] = []
        for board in self._boards:
            if board_resource(board.index) in held or board.lost is not None:
                board.gone_since = None
                continue
            board.gone_since = board.gone_since or now
            if now - board.gone_since >= self.lost_after_s:
                mine = [f for f, (_i, _g, b) in running.items() if b == board.index]
                self._lose(board.index, f"no worker held it for {self.lost_after_s:g} s")
                self.client.cancel(mine)
                stuck += mine
        return stuck

    def lost(self) -> dict[int, str]:
        """Board -> why it was lost."""
        return {b.index: b.lost for b in self._boards if b.lost is not None}


def _group_name(job: BoardJob[Any, Any], g: str | None) -> str:
    name = getattr(job, "group_name", None)
    return str(name(g)) if callable(name) else f"group {g}"


def _placed(folder: RunFolder | None) -> dict[str, int]:
    if folder is None:
        return {}
    path = folder.path(PLACEMENT_FILE)
    try:
        data = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    except (OSError, ValueError):
        return {}
    return {str(k): int(v) for k, v in data.items()} if isinstance(data, dict) else {}


def _record_move(folder: RunFolder | None, g: str, board: int) -> None:
    if folder is None:
        return
    placed = _placed(folder)
    placed[g] = board
    atomic_write_json(folder.path(PLACEMENT_FILE), placed)


# -- the host side ---------------------------------------------------------------------------

@dataclass(frozen=True)
class BoardSet:
    """The boards of a run: ``ports`` (``--boards``: workers on this machine, one a port) or
    ``dask`` (a scheduler's workers, each holding its board), the link options, what the job
    does with each board's files (``use``), ``force`` (outputs of another kind replaced),
    ``reassign`` (a lost board's groups move to the others), ``probe`` (each board opened
    once when the workers start: an unreachable board is one line before any work)."""

    ports: tuple[str, ...] | None
    dask: str | None
    link: Any
    use: Any
    force: bool = False
    reassign: bool = False
    probe: bool = True
    allowed_failures: int | None = None


@dataclass
class BoardsRun:
    """A job over several boards: ``result`` (the job's, from every group's records; None for
    a replicated job), ``per_board`` (a replicated job: each board's records), ``units``
    (group -> the board that ran it), ``boards`` (every board's description and why it was
    lost), ``status``, ``run`` (the host run), ``folder``."""

    result: Any
    status: str
    units: dict[str, dict[str, Any]]
    boards: list[dict[str, Any]]
    per_board: list[BoardResult] = field(default_factory=list)
    run: dict[str, Any] | None = None
    """The host run's identity (uid, history run id, metadata), None when not opened."""
    folder: RunFolder | None = None
    """The run's checkpoint (the one ``on_boards`` opened)."""
    records: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Every unit's record (a job of groups), in the job's unit order."""


def run_on_boards(job: BoardJob[Any, Any], boards: BoardSet, options: RunOptions, *,
                  host: RunOptions | None = None,
                  link: RunLink | None = None,
                  stop_requested: Callable[[], bool] | None = None,
                  emit: Callable[[str, dict[str, Any]], None] | None = None,
                  on_boards: Callable[[list[dict[str, Any]]], RunFolder | None] | None = None,
                  tell: Callable[[str], object] | None = None,
                  task: Callable[..., dict[str, Any]] = run_group,
                  client: Any = None) -> BoardsRun:
    """Run ``job`` over ``boards`` (module doc). ``options``: the record level and metadata
    each board's history run takes, the checkpoint folder; ``host``: the options of the run
    as the host records it (its database ``history``: the user's runs database or
    ``--history``; metadata, command line, progress, seed: a
    :class:`~snan_hil.lab.runner.HostRun` opened once the boards answered, its RunStart
    naming them): its control channel the workers poll and the host looks at, its metadata
    each board's run records too, its document stream the groups' events go to, its progress
    (a group done), and the units of the job that need no board (``host_units()``: run here,
    after the boards answered, before the groups; the events of the units the checkpoint
    holds, ``checkpoint_events(folder)``, go to the stream first); without it, ``link`` (the
    control channel and metadata the workers poll and record, :class:`RunLink`),
    ``stop_requested`` and ``emit``. ``on_boards(descriptions)``: told once the boards
    answered, before anything runs (the caller prints them, opens the run's checkpoint with
    the boards' identities and returns it, or None: ``options.folder``); ``tell(line)``:
    where the host run says where it is recorded; ``client``: a Dask client of boards
    already started (tests); else ``boards.ports`` start a ``LocalCluster`` or
    ``boards.dask`` is connected to. UserError (one line) for a board that does not open, a
    user mistake in a group; BoardLinkError (one line) for a lost board without reassign;
    StopRequested after a stop."""
    from contextlib import ExitStack, nullcontext
    if client is not None:
        cluster: Any = nullcontext(client)
    elif boards.ports is not None:
        cluster = local_boards(list(boards.ports), allowed_failures=boards.allowed_failures)
    else:
        cluster = connect_scheduler(str(boards.dask))
    plugin = BoardPlugin(boards.use, boards.link, force=boards.force,
                         cwd=os.getcwd() if boards.ports is not None else None,
                         probe=boards.probe, command=options.command,
                         ports=dict(enumerate(boards.ports)) if boards.ports else None)
    with cluster as dask_client, ExitStack() as stack:
        found = install_boards(dask_client, plugin,
                               expect=len(boards.ports) if boards.ports is not None else None)
        folder = on_boards(found) if on_boards is not None else None
        if folder is not None:
            options = dataclasses.replace(options, folder=folder)
        here = None
        if host is not None:
            here = stack.enter_context(HostRun(
                job, dataclasses.replace(host, folder=options.folder), port=None,
                protocol=boards.link.protocol,
                config={**job.describe(), "boards": [_brief(b) for b in found]}))
            if here.path is not None and tell is not None:
                tell(f"recorded in {here.path} (follow it: snan-hil watch --history "
                     f"{here.path})")
            m = here.metadata
            link = link or RunLink(history=str(here.path) if here.path is not None else None,
                                   uid=here.uid, metadata={"sample": m.sample,
                                                           "operator": m.operator,
                                                           "note": m.note,
                                                           "tags": tuple(m.tags)})
            stop_requested = stop_requested or here.stop_requested
            emit = emit or here.emit
        fan = Fanout(dask_client, found, reassign=boards.reassign,
                     stop_requested=stop_requested, emit=emit, task=task)
        base = GroupTask(None, link or RunLink(), None if options.record == "off"
                         else options.record, options.command, options.seed, options.folder)
        groups_of = getattr(job, "groups", None)
        if callable(groups_of):
            result, units, records = _grouped(job, fan, base, [str(g) for g in groups_of()],
                                              options, here, len(found))
            per_board: list[BoardResult] = []
        else:
            result, units, records = None, {}, {}
            per_board = _replicated(job, fan, base, found)
        descriptions = _describe(dask_client, found, fan.lost())
        if here is not None:
            here.finish("complete", result, extra={"boards": [
                {**_brief(b), "lost": b.get("lost")} for b in descriptions]})
    return BoardsRun(result, "complete", units, descriptions,
                     sorted(per_board, key=lambda r: r.board),
                     run=here.run_block() if here is not None else None,
                     folder=options.folder, records=records)


def _brief(board: dict[str, Any]) -> dict[str, Any]:
    """A board as the host run records it: number, port, board id."""
    return {"board": board.get("board"), "port": board.get("port"),
            "board_id": (board.get("identity") or {}).get("board_id")}


def _grouped(job: BoardJob[Any, Any], fan: Fanout, base: GroupTask, groups: list[str],
             options: RunOptions, host: HostRun | None, n_boards: int
             ) -> tuple[Any, dict[str, dict[str, Any]], dict[str, dict[str, Any]]]:
    """A job of groups: its units without a board run here (``host_units()``), then each
    group on its board; the job's result from every unit's record, the group -> who ran it,
    the records."""
    records: dict[str, dict[str, Any]] = {}
    units: dict[str, dict[str, Any]] = {}
    here = getattr(job, "host_units", None)
    mine = list(here()) if callable(here) else []
    if mine:
        runner = host if host is not None else \
            HostRun(job, dataclasses.replace(options, record="off", subscribers=()))
        runner.run_units(mine, records)
    taken = getattr(job, "checkpoint_events", None)
    if callable(taken) and fan.emit is not None:     # the stream holds the whole run
        for stream, data in taken(options.folder):
            fan.emit(stream, data)
    cost_of = getattr(job, "group_cost", None)
    cost = cost_of() if callable(cost_of) and len(groups) > n_boards else None
    where = fan.place(groups, cost, options.folder)
    log.info("groups per board: %s", where)
    bar = track(host.progress if host is not None else None, "groups", len(groups))

    def done(g: str | None, payload: dict[str, Any]) -> None:
        records.update(payload["records"])
        units[str(g)] = payload["unit"]
        bar.advance(1, f"{_group_name(job, g)}: done on board {payload['board']}")
    fan.run(job, [(g, where[g]) for g in groups], base, done)
    ordered = _in_unit_order(job, records)
    return job.result(ordered, "complete"), units, ordered


def _replicated(job: BoardJob[Any, Any], fan: Fanout, base: GroupTask,
                found: list[dict[str, Any]]) -> list[BoardResult]:
    """A job without groups: the whole job on every board's own chip."""
    per_board: list[BoardResult] = []

    def done(_g: str | None, payload: dict[str, Any]) -> None:
        per_board.append(BoardResult(int(payload["board"]), payload["unit"],
                                     payload["records"], payload.get("run", {})))
    fan.run(job, [(None, int(b["board"])) for b in found], base, done)
    return per_board


def _in_unit_order(job: BoardJob[Any, Any], records: dict[str, dict[str, Any]]
                   ) -> dict[str, dict[str, Any]]:
    order = getattr(job, "unit_order", None)
    if callable(order):
        keys = [k for k in order() if k in records]
        return {k: records[k] for k in keys}
    return dict(records)


def _describe(client: Any, found: list[dict[str, Any]], lost: dict[int, str]
              ) -> list[dict[str, Any]]:
    try:
        now = {d.get("board"): d for d in client.run(_describe_worker).values()
               if d.get("port") is not None}
    except Exception:                   # noqa: BLE001 - a lost worker: the earlier view
        now = {}
    return [{**b, **now.get(b["board"], {}), "lost": lost.get(int(b["board"]))}
            for b in found]
