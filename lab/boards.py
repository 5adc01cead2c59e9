"""Several boards in one run: boards as Dask worker resources (issue 25).

Each board is held by one Dask worker (one process, one thread). The worker declares the
resources ``board=1`` and ``board-<i>=1`` (``i``: the board's number in the run, 0..B-1) and
gets its port in the environment variable ``SNAN_HIL_BOARD`` (:data:`PORT_ENV`). The run
installs :class:`BoardPlugin` (a ``distributed.WorkerPlugin``) on every worker: it opens the
worker's board through the opener (:func:`snan_hil.lab.opener.plan_board`, so each board keeps
its own layout, program report and history as the opener resolves them), holds the session
for the worker's life and closes it on teardown.

The unit of work is one weight set on one board (:func:`board_unit`: program, launch the
scenarios, return the set's record, :func:`snan_hil.host.hil.compare.run_unit`), submitted with
``resources={"board-<i>": 1}`` — a board runs one unit at a time — and chained after the
board's previous unit, so each board runs its sets in order. Dask schedules; nothing here does.

Which set runs where (:func:`assign`): with no more sets than boards, the set at position ``p``
of the run's sets (their order in ``--weight-set``, else 0, 1, ...) runs on board ``p``; with
more, the sets are balanced over the boards by the board time each is predicted to take
(:func:`~snan_hil.host.hil.compare.predicted_board_cost`: programming plus the decisions of
its launches, from the set's software launches, which are deterministic), longest first, so
the assignment is a pure function of the run's request and a resumed set goes back to its
board. Each board runs its sets in the run's order, each from a fresh boot, as a one-board
run of those sets on that chip would. With
emulated chips the launches are therefore bit-identical to ``compare --port CHIP --weight-set
<its sets>`` on a copy of the chip, and chips made alike (same seed, fresh) give identical
results whichever board held them.

A board lost mid-run (its worker killed, its port gone): the units it finished are committed
to the run's checkpoint as they come back. A worker that comes back (a ``LocalCluster``'s
nanny restarts it; Dask reruns the unit that was running, up to
``distributed.scheduler.allowed-failures`` times) simply carries on. A board whose unit fails,
or that no worker holds for ``lost_after_s``, is lost: the other boards finish their units,
then the run stops with one line (resume it with ``--resume``; its unfinished sets go back to
the same board) — or, with ``reassign``, the lost board's sets move to the other boards (each
set is programmed there first, as every set is). Pulses are never applied twice: a set that is
rerun starts again from what its chip holds (write-and-verify reads before it writes).
``learn``'s sessions (:meth:`BoardPool.run_sessions`) are lost and moved the same way; a moved
session goes on from its last committed cycle, the new chip reprogrammed to the session's
weights first (:mod:`snan_hil.host.hil.learn`).

On one machine (``--boards PORT,PORT,...``): :func:`local_boards` starts a
``distributed.LocalCluster`` with one worker process per board. With a scheduler of your own
(``--dask tcp://host:8786``): start one worker per board, e.g.::

    SNAN_HIL_BOARD=/dev/ttyUSB0 dask worker tcp://host:8786 --nworkers 1 --nthreads 1 \\
        --resources "board=1,board-0=1"

(docs/multiboard.md has the whole recipe).
"""

from __future__ import annotations

import logging
import os
import re
import socket
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from snan_hil.board.session import BoardSession
from snan_hil.calibration.control import ControlledClient
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.programmer import ProgramConfig
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.files.atomicio import atomic_write_bytes, atomic_write_text
from snan_hil.host.hil.compare import CompareRequest, predicted_board_cost, run_unit
from snan_hil.host.hil.learn import ChipContext, run_chip_session
from snan_hil.host.hil.report import measure_spike_geometry
from snan_hil.lab.opener import BoardPlan, FileUse, plan_board
from snan_hil.records.control import RunControl, StopRequested
from snan_hil.records.documents import RunMetadata
from snan_hil.records.history import Recorder
from snan_hil.lab.ports import BoardAddress

try:                                    # the Dask extra; without it --boards says so
    from distributed import WorkerPlugin
except ImportError:                     # pragma: no cover - the test extra has distributed
    WorkerPlugin = object   # type: ignore[misc,assignment]  # stands in for the base class

__all__ = ["PORT_ENV", "PLUGIN_NAME", "BOARD_RESOURCE", "LinkOptions", "BoardPlugin",
           "board_resource", "check_ports", "assign", "board_unit", "local_boards",
           "connect_scheduler", "BoardPool", "RunLink", "UnitStopped"]

log = logging.getLogger(__name__)

PORT_ENV = "SNAN_HIL_BOARD"
"""The environment variable that gives a worker the port of its board."""

PLUGIN_NAME = "snan-hil-board"
"""The name :class:`BoardPlugin` is installed under on every worker."""

BOARD_RESOURCE = "board"
"""The resource every board-holding worker declares (``board=1``)."""

_RESOURCE = re.compile(r"^board-(\d+)$")


def board_resource(i: int) -> str:
    """The resource of board ``i`` (``board-<i>``), declared by the one worker that holds
    it."""
    return f"{BOARD_RESOURCE}-{int(i)}"


@dataclass(frozen=True)
class LinkOptions:
    """The link options every board of the run is opened with (as ``--protocol``,
    ``--baud`` (bit/s), ``--timeout`` (s), ``--mcu``, ``--max-write-v`` (V))."""

    protocol: str = "framed"
    baud: int = 115200
    timeout: float | None = None
    mcu: str | None = None
    max_write_v: float | None = None

    def address(self, port: str) -> BoardAddress:
        return BoardAddress(port, protocol=self.protocol, baud=self.baud, timeout=self.timeout,
                            mcu=self.mcu, max_write_v=self.max_write_v)


def check_ports(ports: Sequence[str], link: LinkOptions) -> list[str]:
    """``--boards``: the ports, checked before any work — at least two, each a port the
    options can take (:meth:`BoardAddress.check`), no board twice (two ports naming one
    emulated chip file count as one board), no empty entry (``A,,B``). UserError (one line)
    otherwise."""
    given = [p.strip() for p in ports]
    if len(given) > 1 and "" in given:
        where = given.index("") + 1
        raise UserError(f"--boards: entry {where} of {','.join(given)!r} is empty; give "
                        "the ports separated by single commas")
    ports = [p for p in given if p]
    if len(ports) < 2:
        raise UserError(f"--boards needs two ports or more, got {len(ports)} "
                        f"({','.join(ports) or 'none'}); for one board give --port")
    seen: dict[str, str] = {}
    for port in ports:
        address = link.address(port)
        address.check()
        state = address.chip_state
        key = f"chip:{state.expanduser().resolve()}" if state is not None else f"port:{port}"
        if key in seen:
            raise UserError(f"--boards: {port} is the same board as {seen[key]}; give each "
                            "board once")
        seen[key] = port
    return ports


def assign(sets: Sequence[int], boards: int,
           cost: Mapping[int, float] | None = None) -> dict[int, int]:
    """Set index -> board number (see the module docstring). Without ``cost``: the set at
    position p of ``sets`` on board ``p mod boards``. With ``cost`` (per set, e.g. its board
    time predicted by :func:`~snan_hil.host.hil.compare.predicted_board_cost`): longest
    processing time first (Graham 1969: the costliest set next goes to the board with the
    least so far; the largest board's sum is within 4/3 of the best split), ties to the
    earlier position and the lower board; then the boards are numbered by the position of
    their first set, so with no more sets than boards set p is on board p as without cost.
    A pure function of its arguments: a resumed run puts every set back on its board."""
    order = [int(k) for k in sets]
    if cost is None or len(order) <= boards:
        return {k: p % boards for p, k in enumerate(order)}
    pos = {k: p for p, k in enumerate(order)}
    load = [0.0] * boards
    group: list[list[int]] = [[] for _ in range(boards)]
    for k in sorted(order, key=lambda k: (-float(cost[k]), pos[k])):
        b = min(range(boards), key=lambda i: (load[i], i))
        load[b] += float(cost[k])
        group[b].append(k)
    numbered = sorted((g for g in group if g), key=lambda g: min(pos[k] for k in g))
    return {k: b for b, g in enumerate(numbered) for k in g}


# -- the worker side -----------------------------------------------------------------------

class BoardPlugin(WorkerPlugin):
    """Opens the worker's board (port in ``$SNAN_HIL_BOARD``, or ``port``) when installed,
    holds its session for the worker's life, closes it on teardown. ``use``: what the job does
    with the board's files (:class:`FileUse`); ``force``: outputs of another kind may be
    replaced; ``ports``: board number -> port, instead of the workers' ``$SNAN_HIL_BOARD``
    (one cluster lending its workers to runs on other chips, e.g. the tests); ``cwd``: the
    folder the caller's relative paths are relative to (workers on its machine); ``probe``
    False: the board is not opened here (a job that opens it itself, so its chip boots as
    often as in a one-board run). A worker
    without a port holds no board. A board that cannot be opened is recorded (:attr:`error`,
    one line) rather than raised, so the run reports it in one line."""

    name = PLUGIN_NAME

    def __init__(self, use: FileUse, link: LinkOptions, *, force: bool = False,
                 port: str | None = None, command: str = "snan-hil compare",
                 ports: dict[int, str] | None = None, cwd: str | None = None,
                 probe: bool = True) -> None:
        self.use, self.link, self.force, self.port = use, link, force, port
        self.probe = probe
        self.ports = dict(ports or {})
        self.cwd = cwd
        self.command = command
        self.plan: BoardPlan | None = None
        self.session: BoardSession | None = None
        self.error: str | None = None
        self.index: int | None = None
        self.worker_address = ""
        self.warm = False               # the kernels are loaded (a unit ran here)

    def setup(self, worker: Any) -> None:
        self.worker_address = str(getattr(worker, "address", ""))
        if self.cwd is not None and Path(self.cwd).is_dir():
            os.chdir(self.cwd)          # the caller's relative paths, on its machine
        resources = _resources_of(worker)
        held = [int(m.group(1)) for r in resources if (m := _RESOURCE.match(r))]
        self.index = held[0] if len(held) == 1 else None
        port = self.ports.get(self.index) if self.index is not None else None
        port = port or self.port or os.environ.get(PORT_ENV) or None
        self.port = port
        if port is None:
            return
        if len(held) != 1:
            self.error = (f"the worker {self.worker_address} holding {port} declares "
                          f"{len(held)} board-<i> resources; start it with --resources "
                          "board=1,board-<i>=1 (one i per board)")
            return
        if not self.probe:              # the job opens its board itself, as on one board
            return
        try:
            plan = plan_board(self.link.address(port), self.use, force=self.force,
                              options=f"--port {port}")
            session = plan.open()
            session.close()             # the units open it afresh; the session describes it
        except UserError as exc:
            self.error = f"board {self.index} ({port}): {exc}"
            return
        except Exception as exc:        # noqa: BLE001 - a board that does not answer
            self.error = f"board {self.index} ({port}) cannot be opened: " \
                         f"{type(exc).__name__}: {exc}"
            return
        self.plan, self.session = plan, session
        log.info("board %s on %s: %s", self.index, port, session.identity.board_id)

    def teardown(self, worker: Any) -> None:
        if self.session is not None:
            self.session.close()
            log.info("board %s on %s closed", self.index, self.port)

    def describe(self) -> dict[str, Any]:
        """What the run records of this worker's board: number, port, worker, error, identity
        and the session's snapshot (``snan-hil-session/1``)."""
        s = self.session
        return {"board": self.index, "port": self.port, "worker": self.worker_address,
                "error": self.error,
                "identity": s.identity.to_dict() if s is not None else None,
                "protocol": s.protocol if s is not None else None,
                "baud": s.baud if s is not None else None,
                "session": s.snapshot() if s is not None else None}

    def held(self) -> BoardSession:
        """The session of the board (RuntimeError naming the reason when there is none)."""
        if self.session is None:
            raise RuntimeError(self.error or f"the worker {self.worker_address} holds no board")
        return self.session

    def run_set(self, request: CompareRequest, index: int, seed: int | None,
                level: str | None, boundary: str | None = None,
                run: RunLink | None = None) -> dict[str, Any]:
        """One set on this board (:func:`run_unit`), its programming recorded into the
        board's history database when ``level`` is given; the record gets ``"unit"``: board
        number, port, board id, worker. ``boundary`` (a folder this worker can write, e.g. in
        the run's checkpoint): an emulated chip and its layout are saved there before the set
        and, when the set is run again (its worker died, the run is resumed), put back first,
        so the rerun gives what an uninterrupted run gives. ``run``: the run's control
        channel (pause / stop before each board request; a stop raises :class:`UnitStopped`)
        and metadata (:class:`RunLink`)."""
        session = self.held()
        if boundary is not None:
            self._boundary(Path(boundary) / f"board-{self.index}" / f"before-set-{index}",
                           session)
        history = session.files.history if level is not None else None
        unit = {"board": self.index, "port": self.port,
                "board_id": session.identity.board_id, "worker": self.worker_address}
        warm, self.warm = not self.warm, True
        control = _control(run)
        watch = None if control is None else \
            (lambda client: ControlledClient(client, control.check))
        try:
            if history is None:
                record = run_unit(request, index, session, warm_up=warm, watch=watch)
            else:
                meta = RunMetadata(**(run.metadata if run is not None else {}))
                with Recorder(history, "program", command=self.command,
                              level=level or "pulses", warn=log.warning, port=self.port,
                              protocol=session.protocol, seed=seed, metadata=meta,
                              **session.identity.to_dict()) as rec:
                    record = run_unit(request, index, session, program_observer=rec,
                                      warm_up=warm, watch=watch)
                    rec.finish("complete", record.get("programming"))
        except StopRequested as stop:
            raise UnitStopped(f"set {index} on board {self.index}: {stop}") from None
        finally:
            if control is not None:
                control.close()
        return {**record, "unit": unit}

    def _boundary(self, folder: Path, session: BoardSession) -> None:
        """Save the chip and layout into ``folder``, or put them back if saved already."""
        snapshots, layout = session.snapshots, session.files.layout
        if snapshots is None:
            return                      # a real chip cannot be put back
        chip, saved = folder / "chip", folder / "layout.json"
        done = folder / "saved"
        if done.is_file():
            snapshots.check(chip)
            snapshots.restore(chip)
            if layout is not None:
                if saved.is_file():
                    atomic_write_bytes(layout, saved.read_bytes())
                else:
                    layout.unlink(missing_ok=True)
            log.info("board %s: chip and layout put back from %s", self.index, folder)
            return
        folder.mkdir(parents=True, exist_ok=True)
        snapshots.save(chip)
        if layout is not None and layout.is_file():
            atomic_write_bytes(saved, layout.read_bytes())
        atomic_write_text(done, "chip and layout saved before the set\n")

    def geometry(self, request: CompareRequest) -> dict[str, Any] | None:
        """The 15 x 8 spike measurement of the speed/energy report on this board."""
        with self.held().reopen() as session:
            row_code = session.info.read_code
            layout = session.files.layout
            if layout is not None and layout.is_file():
                chain = Layout.load(layout).read_chain
                row_code = chain.read_code if chain is not None else row_code
            return measure_spike_geometry(session.client, row_code=row_code,
                                          baud=session.baud)


def _control(run: RunLink | None) -> RunControl | None:
    """The worker's own poll of the run's control channel (None: no database)."""
    if run is None or run.history is None or run.uid is None:
        return None
    return RunControl(run.history, run.uid, warn=log.warning)


def _resources_of(worker: Any) -> dict[str, float]:
    state = getattr(worker, "state", None)
    found = getattr(state, "total_resources", None) or getattr(worker, "total_resources", None)
    return dict(found or {})


def _plugin() -> BoardPlugin:
    from distributed import get_worker          # the dask extra (see the import above)
    plugin = get_worker().plugins.get(PLUGIN_NAME)
    if not isinstance(plugin, BoardPlugin):
        raise RuntimeError("this Dask worker has no snan-hil board plugin")
    return plugin


def board_unit(request: CompareRequest, index: int, seed: int | None = None,
               level: str | None = None, after: Any = None,
               boundary: str | None = None, run: RunLink | None = None) -> dict[str, Any]:
    """The task of one unit (runs on the worker holding the board): set ``index`` of
    ``request`` on the worker's board (:meth:`BoardPlugin.run_set`). ``after``: the board's
    previous unit (its result is not used: it only orders the board's units); ``boundary``,
    ``run``: see :meth:`BoardPlugin.run_set`."""
    return _plugin().run_set(request, index, seed, level, boundary, run)


class UnitStopped(Exception):
    """A unit that a stop from ``snan-hil watch`` ended before its next board request
    (:class:`~snan_hil.records.control.StopRequested` on the worker, which Dask would take
    for the worker's own interrupt); the run stops as on one board (exit 130, resumable)."""


@dataclass(frozen=True)
class RunLink:
    """What a unit knows of the run it belongs to: the history database holding the run
    (``history``: its control channel, polled by the worker before each board request, so
    ``snan-hil watch`` pauses and stops every board; a path the worker cannot read leaves
    the channel off with one warning) and the run's ``uid``; the user's ``metadata``
    (sample, operator, note, tags: :class:`~snan_hil.records.documents.RunMetadata` fields)
    that each board's own history record of the unit carries too."""

    history: str | None = None
    uid: str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)


def learn_unit(cfg: Any, lc: Any, model: Any, k: int, folder: Any, level: str | None,
               command: str = "snan-hil learn", after: Any = None) -> dict[str, Any]:
    """The task of one learning session (``learn --boards``/``--dask``): chip session ``k``
    on the worker's board (a fresh connection; the weight map of the board's own layout; its
    pulses recorded into the board's history when ``level`` is given), the session's record
    (:func:`snan_hil.host.hil.learn.run_chip_session`) with ``unit``. ``after``: the board's
    previous session (orders the board's sessions only)."""
    plugin = _plugin()
    with plugin.held().reopen() as session:
        layout = session.files.layout
        wm = Layout.load(layout).weight_map if layout is not None and layout.is_file() \
            else WeightMap()
        unit: dict[str, Any] = {"board": plugin.index, "port": plugin.port,
                                "board_id": session.identity.board_id,
                                "worker": plugin.worker_address}
        history = session.files.history if level is not None else None
        if history is None:
            record = run_chip_session(cfg, lc, model, k, ChipContext(
                session, ProgramConfig(weight_map=wm), board=plugin.index), folder)
        else:
            with Recorder(history, "learn", command=command, level=level or "runs",
                          warn=log.warning,
                          port=plugin.port, protocol=session.protocol, seed=lc.seed,
                          **session.identity.to_dict()) as rec:
                record = run_chip_session(cfg, lc, model, k, ChipContext(
                    session, ProgramConfig(weight_map=wm), observer=rec,
                    board=plugin.index), folder)
                mine = sum(r["set"] + r["reset"] for r in record["ledger"].get("rows", [])
                           if r.get("board", plugin.index) == plugin.index)
                rec.finish("complete", {"session": k, "pulses": mine})
    moves = record.get("moves") or []
    if moves:                           # the session moved here from a lost board
        unit.update(moved_from=moves[-1]["from"], moved_at_cycle=moves[-1]["at_cycle"],
                    moves=moves)
    return {**record, "unit": unit}


def _describe_worker(dask_worker: Any) -> dict[str, Any]:
    """Run by ``Client.run`` on each worker (Dask passes the worker)."""
    plugin = dask_worker.plugins.get(PLUGIN_NAME)
    return plugin.describe() if isinstance(plugin, BoardPlugin) else {"port": None}


def _geometry_unit(request: CompareRequest, after: Any = None) -> dict[str, Any] | None:
    return _plugin().geometry(request)


# -- the client side -----------------------------------------------------------------------

@contextmanager
def local_boards(ports: Sequence[str], *, allowed_failures: int | None = None) -> Iterator[Any]:
    """A ``distributed.LocalCluster`` on this machine with one worker process per port (one
    thread; resources ``board=1``, ``board-<i>=1``; ``$SNAN_HIL_BOARD`` = its port), yielded
    as a connected ``distributed.Client``; closed on the way out. ``allowed_failures``: how
    often a unit is rerun after its worker died (None: Dask's default). The workers are
    forked from a forkserver that imported :data:`WORKER_PRELOAD` once (not spawned: each
    would import snan-hil itself), with the caller's environment as it is now."""
    import dask                                 # the dask extra (see the import above)
    from distributed import Client, LocalCluster
    config: dict[str, Any] = {"distributed.worker.multiprocessing-method": "forkserver"}
    if allowed_failures is not None:
        config["distributed.scheduler.allowed-failures"] = int(allowed_failures)
    # for the cluster's life: a worker its nanny restarts is forked the same way
    with dask.config.set(config):
        _preload_forkserver()
        cluster = LocalCluster(n_workers=0, processes=True, threads_per_worker=1,
                               # a unit's failure is the run's one line, not a
                               # worker's traceback
                               dashboard_address=None, silence_logs=logging.CRITICAL,
                               # no dashboard; its health page on a free port (8787 may
                               # be another cluster's)
                               scheduler_kwargs={"dashboard": False,
                                                 "dashboard_address": "127.0.0.1:0"})
        try:
            spec = cluster.new_spec
            for i, port in enumerate(ports):
                options = {**spec["options"], "nthreads": 1,
                           "resources": {BOARD_RESOURCE: 1, board_resource(i): 1},
                           # the caller's environment as it is now: the forkserver's
                           # is the one it started with
                           "env": {**os.environ, PORT_ENV: port}}
                cluster.worker_spec[board_resource(i)] = {"cls": spec["cls"],
                                                          "options": options}
            cluster.sync(cluster._correct_state)    # the workers start together
            client = Client(cluster)
            try:
                client.wait_for_workers(len(ports))
                yield client
            finally:
                client.close()
        finally:
            cluster.close()


#: What the worker processes of :func:`local_boards` import once, in the forkserver they are
#: forked from, instead of each on its own (the units' code: kernels, emulator, programmer).
WORKER_PRELOAD = ("snan_hil.lab.boards", "snan_hil.host.hil.compare",
                  "snan_hil.firmware_emu.emulator")


def _preload_forkserver() -> None:
    """Workers of :func:`local_boards` are forked from one forkserver that has imported
    :data:`WORKER_PRELOAD` (and Dask's own packages) once: with ``spawn`` (Dask's default)
    every worker imports them itself and re-imports the caller's main module, several
    seconds each on a small machine (bench/bench_multiboard.py). Must run before the
    forkserver starts (the first worker of the process); later calls change nothing."""
    from distributed.utils import get_mp_context   # the dask extra
    ctx = get_mp_context()              # sets Dask's own forkserver preload the first time
    ctx.set_forkserver_preload(["distributed", *WORKER_PRELOAD,
                                "snan_hil.lab.worker_signals"])


@contextmanager
def connect_scheduler(address: str, timeout_s: float = 10.0) -> Iterator[Any]:
    """A ``distributed.Client`` of the scheduler at ``address`` (``tcp://host:8786``);
    UserError (one line) when none answers there."""
    try:
        from distributed import Client          # the dask extra
    except ImportError:                 # pragma: no cover
        raise UserError("--dask needs the dask extra: pip install 'snan-hil[dask]'") from None
    _refused(address)
    try:
        client = Client(address, timeout=f"{timeout_s}s")
    except (OSError, TimeoutError, ValueError, TypeError, MemoryError) as exc:
        raise UserError(f"cannot reach the Dask scheduler at {address}: "
                        f"{exc.__class__.__name__}; start one (dask scheduler) or check the "
                        "address") from None
    try:
        yield client
    finally:
        client.close()


def _refused(address: str) -> None:
    """UserError (one line) at once when nothing listens at a ``tcp://host:port`` address
    (Dask's client would retry it for its whole timeout); other addresses are left to Dask."""
    try:
        url = urlsplit(address)
        host, port = url.hostname, url.port
    except ValueError:
        return
    if url.scheme != "tcp" or host is None or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=2.0).close()
    except ConnectionRefusedError:
        raise UserError(f"cannot reach the Dask scheduler at {address}: nothing listens "
                        "there; start one (dask scheduler) or check the address") from None
    except OSError:
        return                          # slow or unresolved: Dask's own wait decides


@dataclass
class _Board:
    index: int
    info: dict[str, Any]
    last: Any = None                    # the future of its last submitted unit
    lost: str | None = None
    gone_since: float | None = None


@dataclass
class BoardPool:
    """The boards of a run, held by the workers of ``client`` (:class:`BoardPlugin`
    installed by :meth:`install`); a :class:`~snan_hil.host.hil.compare.UnitRunner` for
    :func:`~snan_hil.host.hil.compare.run_compare`. ``reassign``: a lost board's sets move to
    the other boards; ``lost_after_s``: how long a board may have no worker before it counts
    as lost; ``level``: the history record level of the programming (None: not recorded);
    ``seed``: recorded with it; ``boundary``: the folder where emulated chips are saved
    before each set (:meth:`BoardPlugin.run_set`; the workers must reach it: on one machine,
    the run's checkpoint); ``unit``: the task function (tests replace it); ``run``: the run's
    control channel and metadata for the units (:class:`RunLink`); ``stop_requested()``:
    polled while the units run (the run's own look at its control channel): once True, no
    further unit starts, the running ones end at their next board request (their workers
    poll the same channel) or finish, and :class:`~snan_hil.records.control.StopRequested`
    is raised (the finished sets are committed: ``--resume`` goes on)."""

    client: Any
    reassign: bool = False
    lost_after_s: float = 60.0
    poll_s: float = 1.0
    level: str | None = None
    seed: int | None = None
    boundary: str | None = None
    unit: Callable[..., dict[str, Any]] = board_unit
    run: RunLink | None = None
    stop_requested: Callable[[], bool] | None = None
    learner: Callable[..., dict[str, Any]] = learn_unit
    """The task of one learning session (:meth:`run_sessions`; tests replace it)."""
    boards: list[_Board] = field(default_factory=list)
    moved: dict[int, int] = field(default_factory=dict)

    def install(self, plugin: BoardPlugin, expect: int | None = None) -> list[dict[str, Any]]:
        """Install ``plugin`` on every worker (each opens its board) and collect the boards:
        one per ``board-<i>`` worker, numbered 0..B-1. UserError (one line) for a board that
        cannot be opened, a number held twice or missing, fewer than two boards, or
        ``expect`` boards not found."""
        self.client.register_plugin(plugin, name=PLUGIN_NAME)
        found = [d for d in self.client.run(_describe_worker).values()
                 if d.get("port") is not None]
        for d in found:
            if d.get("error"):
                raise UserError(d["error"])
        numbers = sorted(int(d["board"]) for d in found)
        if len(found) < 2:
            raise UserError(f"the Dask scheduler has {len(found)} worker(s) holding a board; "
                            f"several boards need two or more (start one worker per board, "
                            f"{PORT_ENV}=PORT dask worker ... --resources "
                            "board=1,board-<i>=1)")
        if numbers != list(range(len(found))):
            raise UserError(f"the workers hold boards {numbers}; number them 0.."
                            f"{len(found) - 1}, each once (--resources board=1,board-<i>=1)")
        if expect is not None and len(found) != expect:
            raise UserError(f"{len(found)} boards answered, {expect} expected")
        self.boards = [_Board(int(d["board"]), d)
                       for d in sorted(found, key=lambda d: int(d["board"]))]
        return [b.info for b in self.boards]

    @property
    def baud(self) -> int:
        return int(self.boards[0].info.get("baud") or 115200)

    # -- UnitRunner ---------------------------------------------------------------------------
    def run_units(self, request: CompareRequest, pending: list[int],
                  commit: Callable[[int, dict[str, Any]], None]) -> None:
        """Every set of ``pending`` as one unit on its board (:func:`assign`), committed as
        it comes back; a lost board's sets moved (``reassign``) or, once the other boards are
        done, UserError (one line: resume later)."""
        from distributed import wait            # the dask extra
        order = list(request.sets) if request.sets is not None else sorted(pending)
        # over all the run's sets, so a resumed set goes back to its board; balanced by the
        # board time each set is predicted to take (its software launches)
        cost = predicted_board_cost(request) if len(order) > len(self.boards) else None
        where = assign(order, len(self.boards), cost)
        log.info("sets per board: %s", {b.index: [k for k in order if where[k] == b.index]
                                        for b in self.boards})
        where.update({k: b for k, b in self.moved.items() if k in where})
        running: dict[Any, tuple[int, int]] = {}
        for k in order:
            if k in pending:
                running[self._submit(request, k, where[k])] = (k, where[k])
        stopping = False
        while running:
            try:
                done, _ = wait(list(running), timeout=self.poll_s,
                               return_when="FIRST_COMPLETED")
            except TimeoutError:
                done = set(self._watch(running))
            if not stopping and self.stop_requested is not None and self.stop_requested():
                stopping = True
                self._stop(running)
            for fut in sorted(done, key=lambda f: running[f][0]):     # in set order
                k, b = running.pop(fut)
                if fut.status == "finished":
                    commit(k, fut.result())
                    continue
                if stopping and fut.status == "cancelled" or _stopped(fut):
                    if not stopping:
                        stopping = True
                        self._stop(running)
                    continue
                mistake = _user_error(fut)
                if mistake is not None:     # the input, not the board: stop, board kept
                    self.client.cancel(list(running))
                    raise UserError(f"set {k} on board {b}: {mistake}")
                self._lose(b, f"set {k} failed: {_reason(fut)}")
                if self.reassign:
                    target = self._survivor(k)
                    self.moved[k] = target
                    log.warning("set %s moves from board %s to board %s", k, b, target)
                    running[self._submit(request, k, target)] = (k, target)
        if stopping:
            raise StopRequested("stop requested (snan-hil watch)")
        lost = [board for board in self.boards if board.lost is not None]
        if lost and not self.reassign:
            first = lost[0]
            raise BoardLinkError(f"board {first.index} ({first.info['port']}) was lost "
                            f"({first.lost}); the "
                            "finished sets are kept: run again with --resume when it is back, "
                            "or add --reassign to move its sets to the other boards")

    def _stop(self, running: dict[Any, tuple[int, int]]) -> None:
        """A stop: the units not started yet are cancelled (a running one ends at its next
        board request, its worker seeing the same stop, or finishes and is committed)."""
        log.warning("stop requested: no further set starts")
        waiting = [f for f in running if f.status == "pending"
                   and not self._started(f)]
        if waiting:
            self.client.cancel(waiting)

    def _started(self, fut: Any) -> bool:
        """Whether the unit of ``fut`` is running on its worker already."""
        try:
            states = self.client.run_on_scheduler(_task_states, keys=[fut.key])
        except Exception:                 # noqa: BLE001 - unknown: let it run
            return True
        return states.get(fut.key) in ("processing", "memory", "erred")

    def _submit(self, request: CompareRequest, k: int, b: int) -> Any:
        board = self.boards[b]
        extra = {"run": self.run} if self.run is not None else {}
        fut = self.client.submit(self.unit, request, k, self.seed, self.level, after=board.last,
                                 boundary=self.boundary, resources={board_resource(b): 1},
                                 **extra,
                                 pure=False,
                                 key=f"snan-hil-set-{k}-board-{b}-{uuid.uuid4().hex[:8]}")
        board.last = fut
        return fut

    def _survivor(self, k: int, what: str = "set") -> int:
        alive = [b for b in self.boards if b.lost is None]
        if not alive:
            raise BoardLinkError(f"every board was lost ({what} {k} could not be moved): "
                            + "; ".join(f"board {b.index}: {b.lost}" for b in self.boards)
                            + f"; the finished {what}s are kept: run again with --resume")
        return alive[k % len(alive)].index

    def _lose(self, b: int, reason: str) -> None:
        board = self.boards[b]
        if board.lost is None:
            board.lost = reason
            board.last = None
            log.warning("board %s (%s) lost: %s", b, board.info["port"], reason)

    def _watch(self, running: dict[Any, tuple[int, int]]) -> list[Any]:
        """The units of a board no worker has held for ``lost_after_s``: cancelled and
        returned (they count as failed)."""
        held: set[str] = set()
        for w in self.client.scheduler_info(n_workers=-1).get("workers", {}).values():
            held.update(r for r in (w.get("resources") or {}) if _RESOURCE.match(r))
        now = time.monotonic()
        stuck: list[Any] = []
        for board in self.boards:
            if board_resource(board.index) in held or board.lost is not None:
                board.gone_since = None
                continue
            board.gone_since = board.gone_since or now
            if now - board.gone_since >= self.lost_after_s:
                mine = [f for f, (_k, b) in running.items() if b == board.index]
                self._lose(board.index, f"no worker held it for {self.lost_after_s:g} s")
                self.client.cancel(mine)
                stuck += mine
        return stuck

    def run_sessions(self, cfg: Any, lc: Any, model: Any, folder: Any) -> list[dict[str, Any]]:
        """``learn``'s chip sessions 0..S-1 as units (:attr:`learner`, :func:`learn_unit`):
        session k on board k mod B (a resumed session that had moved: on the board holding it
        in the checkpoint), each board's sessions in order; the records in session order (a
        :data:`snan_hil.host.hil.learn.ChipUnits`). UserError (one line) for a user mistake in
        a session. A board lost (its unit failed, not on a user mistake; or no worker held it
        for ``lost_after_s``): with ``reassign`` its unfinished sessions are resubmitted on a
        board still held (:meth:`_survivor`, after that board's last session), where each goes
        on from its last committed cycle after reprogramming
        (:func:`snan_hil.host.hil.learn.run_chip_session`); without, once the other boards are
        done, UserError (one line: its finished cycles are in the checkpoint, run again with
        --resume)."""
        from distributed import wait            # the dask extra
        running: dict[Any, tuple[int, int]] = {}
        for k in range(int(lc.sessions)):
            b = self._holder(folder, k)
            running[self._submit_session(cfg, lc, model, k, folder, b)] = (k, b)
        records: dict[int, dict[str, Any]] = {}
        while running:
            try:
                done, _ = wait(list(running), timeout=self.poll_s,
                               return_when="FIRST_COMPLETED")
            except TimeoutError:
                done = set(self._watch(running))
            for fut in sorted(done, key=lambda f: running[f][0]):     # in session order
                k, b = running.pop(fut)
                if fut.status == "finished":
                    records[k] = fut.result()
                    continue
                mistake = _user_error(fut)
                if mistake is not None:     # the input, not the board: stop, board kept
                    self.client.cancel(list(running))
                    raise UserError(f"session {k} on board {b}: {mistake}")
                self._lose(b, f"session {k} failed: {_reason(fut)}")
                if self.reassign:
                    target = self._survivor(k, "session")
                    log.warning("session %s moves from board %s to board %s", k, b, target)
                    running[self._submit_session(cfg, lc, model, k, folder, target)] = \
                        (k, target)
        lost = [board for board in self.boards if board.lost is not None]
        if lost and not self.reassign:
            first = lost[0]
            raise BoardLinkError(f"board {first.index} ({first.info['port']}) was lost "
                            f"({first.lost}); the finished cycles are kept: run again with "
                            "--resume when it is back, or add --reassign to move its sessions "
                            "to the other boards")
        return [records[k] for k in range(int(lc.sessions))]

    def _holder(self, folder: Any, k: int) -> int:
        """The board of session ``k``: the one holding it in the checkpoint (it moved there
        in an earlier run), else k mod B."""
        owner = folder.done(f"chip-s{k}-owner") if folder is not None else None
        b = owner.get("board") if owner else None
        return int(b) if b is not None and 0 <= int(b) < len(self.boards) \
            else k % len(self.boards)

    def _submit_session(self, cfg: Any, lc: Any, model: Any, k: int, folder: Any,
                        b: int) -> Any:
        board = self.boards[b]
        fut = self.client.submit(self.learner, cfg, lc, model, k, folder, self.level,
                                 after=board.last, pure=False,
                                 resources={board_resource(b): 1},
                                 key=f"snan-hil-learn-{k}-board-{b}-{uuid.uuid4().hex[:8]}")
        board.last = fut
        return fut

    def geometry(self, request: CompareRequest) -> dict[str, Any] | None:
        """The spike measurement on the first board still held (after its units)."""
        board = next((b for b in self.boards if b.lost is None), None)
        if board is None:
            return None
        fut = self.client.submit(_geometry_unit, request, after=board.last,
                                 resources={board_resource(board.index): 1}, pure=False)
        result: dict[str, Any] | None = fut.result()
        return result

    def board_record(self) -> dict[str, Any]:
        """Board 0's fields as a one-board run records them (port, protocol, baud, board,
        session), and ``boards``: every board's description (:meth:`BoardPlugin.describe`,
        taken again at the end where the board still answers)."""
        now = {d.get("board"): d for d in self.client.run(_describe_worker).values()
               if d.get("port") is not None}
        infos = [{**b.info, **now.get(b.index, {}), "lost": b.lost} for b in self.boards]
        first = infos[0]
        return {"port": first["port"], "protocol": first["protocol"], "baud": first["baud"],
                "board": first["identity"], "session": first["session"], "boards": infos}


def _task_states(dask_scheduler: Any, keys: list[str]) -> dict[str, str]:
    """On the scheduler: the state of each task of ``keys`` (``processing``: on a worker)."""
    return {k: dask_scheduler.tasks[k].state for k in keys if k in dask_scheduler.tasks}


def _stopped(fut: Any) -> bool:
    """Whether the unit of ``fut`` ended on a stop from the control channel."""
    if fut.status != "error":
        return False
    try:
        return isinstance(fut.exception(), UnitStopped)
    except Exception:                   # noqa: BLE001
        return False


def _user_error(fut: Any) -> str | None:
    """The one line of a unit that stopped on a user mistake (UserError: bad weights,
    a config out of bounds, ...), else None (the board failed: lost; so is a unit whose board
    or link failed, BoardLinkError)."""
    if fut.status != "error":
        return None
    try:
        exc = fut.exception()
    except Exception:                   # noqa: BLE001 - not a user mistake we can name
        return None
    if not isinstance(exc, UserError) or isinstance(exc, BoardLinkError):
        return None
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _reason(fut: Any) -> str:
    if fut.status == "cancelled":
        return "cancelled"
    try:
        exc = fut.exception()
    except Exception as err:            # noqa: BLE001 - the reason is all we want
        exc = err
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
