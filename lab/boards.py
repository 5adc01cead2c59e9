"""Several boards in one run: boards as Dask worker resources (issue 25).

Each board is held by one Dask worker (one process, one thread). The worker declares the
resources ``board=1`` and ``board-<i>=1`` (``i``: the board's number in the run, 0..B-1) and
gets its port in the environment variable ``SNAN_HIL_BOARD`` (:data:`PORT_ENV`). The run
installs :class:`BoardPlugin` (a ``distributed.WorkerPlugin``) on every worker
(:func:`install_boards`): it holds the worker's board (the opener's plan,
:func:`snan_hil.lab.opener.plan_board`, so each board keeps its own layout, program report
and history as the opener resolves them) for the worker's life. The worker knows no job:
what runs there is :func:`snan_hil.lab.fanout.run_group`, the one unit loop of every job
(:mod:`snan_hil.lab.fanout` schedules the groups of a job on the boards, Dask places each on
its board's worker: ``resources={"board-<i>": 1}``, a board runs one group at a time).

Which group runs where (:func:`assign`): with no more groups than boards, the group at
position ``p`` runs on board ``p``; with more, the groups are balanced over the boards by the
board time each is predicted to take (a comparison's sets:
:func:`~snan_hil.host.hil.compare.predicted_board_cost`), longest first, so the assignment is
a pure function of the run's request and a resumed group goes back to its board.

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
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from snan_hil.board.session import BoardSession, ChipSnapshots
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.lab.opener import BoardPlan, FileUse, plan_board
from snan_hil.lab.ports import BoardAddress

try:                                    # the Dask extra; without it --boards says so
    from distributed import WorkerPlugin
except ImportError:                     # pragma: no cover - the test extra has distributed
    WorkerPlugin = object   # type: ignore[misc,assignment]  # stands in for the base class

__all__ = ["PORT_ENV", "PLUGIN_NAME", "BOARD_RESOURCE", "LinkOptions", "BoardPlugin",
           "board_resource", "check_ports", "assign", "local_boards", "connect_scheduler",
           "install_boards", "RunLink", "UnitStopped"]

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


def check_ports(ports: Sequence[str], link: LinkOptions, option: str = "--boards"
                ) -> list[str]:
    """``--boards`` (or ``option``: ``--group``): the ports, checked before any work — at
    least two, each a port the options can take (:meth:`BoardAddress.check`), no board twice
    (two ports naming one emulated chip file count as one board), no empty entry (``A,,B``).
    UserError (one line) otherwise."""
    given = [p.strip() for p in ports]
    if len(given) > 1 and "" in given:
        where = given.index("") + 1
        raise UserError(f"{option}: entry {where} of {','.join(given)!r} is empty; give "
                        "the ports separated by single commas")
    ports = [p for p in given if p]
    if len(ports) < 2:
        raise UserError(f"{option} needs two ports or more, got {len(ports)} "
                        f"({','.join(ports) or 'none'}); for one board give --port")
    seen: dict[str, str] = {}
    for port in ports:
        address = link.address(port)
        address.check()
        state = address.chip_state
        key = f"chip:{state.expanduser().resolve()}" if state is not None else f"port:{port}"
        if key in seen:
            raise UserError(f"{option}: {port} is the same board as {seen[key]}; give each "
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

    def snapshots(self) -> ChipSnapshots | None:
        """The emulated chip's snapshots (saved and put back), None for a real chip or a
        worker that holds no board."""
        if self.plan is None and self.port is not None and self.error is None:
            self.plan = plan_board(self.link.address(self.port), self.use, force=self.force,
                                   options=f"--port {self.port}")
        return self.plan.snapshots if self.plan is not None else None

    def open(self) -> BoardSession:
        """A fresh session of the worker's board (a new connection; on an emulated chip a
        fresh boot of the saved chip), the caller's to close; the board's plan made here when
        it was not probed. RuntimeError naming the reason when the worker holds no board."""
        if self.plan is None:
            if self.port is None or self.index is None or self.error is not None:
                raise RuntimeError(self.error
                                   or f"the worker {self.worker_address} holds no board")
            self.plan = plan_board(self.link.address(self.port), self.use, force=self.force,
                                   options=f"--port {self.port}")
        return self.plan.open()


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


def _describe_worker(dask_worker: Any) -> dict[str, Any]:
    """Run by ``Client.run`` on each worker (Dask passes the worker)."""
    plugin = dask_worker.plugins.get(PLUGIN_NAME)
    return plugin.describe() if isinstance(plugin, BoardPlugin) else {"port": None}




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
WORKER_PRELOAD = ("snan_hil.lab.fanout", "snan_hil.host.hil.compare",
                  "snan_hil.host.hil.learn", "snan_hil.firmware_emu.emulator")


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

def install_boards(client: Any, plugin: BoardPlugin, expect: int | None = None
                   ) -> list[dict[str, Any]]:
    """Install ``plugin`` on every worker of ``client`` (each finds its board) and collect
    the boards' descriptions (:meth:`BoardPlugin.describe`): one per ``board-<i>`` worker,
    numbered 0..B-1, in board order. UserError (one line) for a board that cannot be opened,
    a number held twice or missing, fewer than two boards, or ``expect`` boards not found."""
    client.register_plugin(plugin, name=PLUGIN_NAME)
    found = [d for d in client.run(_describe_worker).values() if d.get("port") is not None]
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
    return sorted(found, key=lambda d: int(d["board"]))


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
