"""Sweeps of independent tasks and the executors that run them.

A *sweep* is a list of :class:`Task`: each names a module-level function
``fn(config, params, seed) -> dict`` (a small, JSON-able result), its arguments, and a *key*
(a tuple of strings / numbers that identifies the task inside the sweep). The task's seed
is derived from the sweep's master seed and the key alone (:func:`task_seed`), never from
the order in which tasks run, so every executor gives the same results:

* :class:`SerialExecutor`: one after the other in this process;
* :class:`ProcessExecutor`: a local process pool (default: all cores);
* :class:`DaskExecutor`: an existing Dask distributed cluster (``tcp://host:8786``) or a
  ``distributed.Client`` the caller made (e.g. on a ``LocalCluster``); needs the ``dask``
  extra.

``execute(tasks, progress=cb, task=name, on_result=f)`` returns the results in the order of
``tasks``; in this process, after each finished task, it calls ``f(index, result)`` (a
checkpoint commits the result) and then reports the progress task ``name`` to ``cb``
(:mod:`snan_hil.common.progress`): one unit per unit of task ``weight`` (e.g. trials). Library code
never prints.
"""

from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing
import os
import socket
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, track

log = logging.getLogger(__name__)

TaskFn = Callable[[Any, dict, int], dict]
OnResult = Callable[[int, dict], None]
"""``on_result(index, result)``: called in this process as each task finishes (a checkpoint)."""


def key_text(key: Sequence[Any]) -> str:
    """Canonical text of a task key (JSON, floats as repr) used for seeds and lookups."""
    return json.dumps([k if not isinstance(k, float) else repr(k) for k in key],
                      separators=(",", ":"))


def task_seed(master_seed: int, key: Sequence[Any]) -> int:
    """63-bit seed of the task ``key`` in a sweep seeded ``master_seed``.

    ``SeedSequence([master_seed, sha256(key)...])``: independent of execution order, of the
    other tasks in the sweep and of the executor.
    """
    digest = hashlib.sha256(key_text(key).encode()).digest()
    words = [int.from_bytes(digest[i:i + 4], "little") for i in range(0, 16, 4)]
    ss = np.random.SeedSequence([int(master_seed) & ((1 << 64) - 1), *words])
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


@dataclass
class Task:
    """One independent unit of a sweep (see module doc)."""

    key: tuple
    fn: TaskFn
    config: Any
    params: dict = field(default_factory=dict)
    weight: int = 1          #: progress units (e.g. trials) this task stands for
    #: key the seed is derived from (default: ``key``). Chunks of one condition share it
    #: (and select their trials by index), so the chunk size cannot change a result.
    seed_key: tuple | None = None
    seed: int | None = None  #: set by :func:`seed_tasks`


def seed_tasks(tasks: Sequence[Task], master_seed: int) -> list[Task]:
    """Give every task its seed; keys must be unique within the sweep."""
    seen: set[str] = set()
    for t in tasks:
        text = key_text(t.key)
        if text in seen:
            raise ValueError(f"duplicate task key {t.key!r}")
        seen.add(text)
        t.seed = task_seed(master_seed, t.seed_key if t.seed_key is not None else t.key)
    return list(tasks)


def run_task(task: Task) -> dict:
    """Run one task (in whatever process the executor chose)."""
    if task.seed is None:
        raise ValueError(f"task {task.key!r} has no seed (call seed_tasks first)")
    return task.fn(task.config, task.params, task.seed)


class Executor(Protocol):
    name: str

    def execute(self, tasks: Sequence[Task], progress: ProgressCallback | None = None,
                task: str = "tasks", on_result: OnResult | None = None) -> list[dict]: ...


def _units(tasks: Sequence[Task]) -> int:
    return sum(t.weight for t in tasks)


class SerialExecutor:
    """Run the tasks one after the other in this process."""

    name = "serial"

    def execute(self, tasks: Sequence[Task], progress: ProgressCallback | None = None,
                task: str = "tasks", on_result: OnResult | None = None) -> list[dict]:
        out = []
        bar = track(progress, task, _units(tasks))
        for i, t in enumerate(tasks):
            out.append(run_task(t))
            if on_result is not None:
                on_result(i, out[-1])
            bar.advance(t.weight)
        return out


def default_workers() -> int:
    """All cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


PARENT_POLL_S = 0.5
"""How often a pool worker checks that the process that started it is still alive (s)."""


def _watch_parent(parent_pid: int) -> None:
    """Pool-worker initializer: a daemon thread ends this worker (``os._exit``) once its
    parent process is gone, so a sweep killed with SIGKILL leaves no worker running (it
    would otherwise finish its task and wait for more, orphaned). The check is
    ``os.getppid()`` changing, every :data:`PARENT_POLL_S` s; a worker inside a kernel that
    holds the GIL exits when it next lets go."""
    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


class ProcessExecutor:
    """A local process pool (``spawn`` start method: safe with threads in the parent, e.g.
    a progress bar). ``workers`` = None: all cores. With one worker it runs serially."""

    name = "processes"

    def __init__(self, workers: int | None = None) -> None:
        if workers is not None and workers < 1:
            raise UserError(f"--workers must be >= 1, got {workers}")
        self.workers = workers or default_workers()

    def execute(self, tasks: Sequence[Task], progress: ProgressCallback | None = None,
                task: str = "tasks", on_result: OnResult | None = None) -> list[dict]:
        if self.workers == 1 or len(tasks) <= 1:
            return SerialExecutor().execute(tasks, progress, task, on_result)
        results: list[dict | None] = [None] * len(tasks)
        ctx = multiprocessing.get_context("spawn")
        bar = track(progress, task, _units(tasks))
        # largest first: better load balance at the end of the sweep
        order = sorted(range(len(tasks)), key=lambda i: -tasks[i].weight)
        before = set(multiprocessing.active_children())
        with ProcessPoolExecutor(max_workers=min(self.workers, len(tasks)), mp_context=ctx,
                                 initializer=_watch_parent,
                                 initargs=(os.getpid(),)) as pool:
            pending = {pool.submit(run_task, tasks[i]): i for i in order}
            try:
                while pending:
                    done, _ = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in done:
                        i = pending.pop(fut)
                        results[i] = result = fut.result()
                        if on_result is not None:
                            on_result(i, result)
                        bar.advance(tasks[i].weight)
            except BaseException:
                # Ctrl-C, a stop, a failed task: what finished is committed (on_result); the
                # rest is dropped at once -- leaving the pool would run every queued task
                # (and the ones running to their end) before the command could stop
                pool.shutdown(wait=False, cancel_futures=True)
                for proc in set(multiprocessing.active_children()) - before:
                    proc.terminate()
                raise
        return results  # type: ignore[return-value]


def check_scheduler_listens(address: str, probe_s: float = 2.0) -> None:
    """``ConnectionRefusedError`` at once when nothing listens at a ``tcp://`` scheduler
    ``address`` (``tcp://host:8786`` or ``host:8786``): Dask's own connect retries a refused
    port until its whole timeout (10 s) has passed, though no scheduler is there. A host that
    does not answer within ``probe_s`` s, or any other scheme, is left to Dask's connect."""
    from distributed.comm.addressing import parse_address, parse_host_port   # the dask extra
    scheme, location = parse_address(address)
    if scheme != "tcp":
        return
    host, port = parse_host_port(location)
    try:
        socket.create_connection((host, port), timeout=probe_s).close()
    except ConnectionRefusedError:
        raise
    except OSError:                   # slow, unresolvable, unroutable: Dask says which
        pass


class DaskExecutor:
    """Run the tasks on a Dask distributed cluster.

    ``address`` (``tcp://host:8786``) connects to a running scheduler; or pass a
    ``distributed.Client`` as ``client`` (the caller keeps ownership). The workers need this
    package installed (same version) and import it by name.
    """

    name = "dask"

    def __init__(self, address: str | None = None, client: Any = None,
                 timeout_s: float = 10.0) -> None:
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise UserError("--dask needs the dask extra: pip install 'snan-hil[dask]'"
                            ) from None
        if client is None and not address:
            raise UserError("--dask needs a scheduler address such as tcp://host:8786")
        self.address = address
        self._client = client
        self.timeout_s = timeout_s

    def execute(self, tasks: Sequence[Task], progress: ProgressCallback | None = None,
                task: str = "tasks", on_result: OnResult | None = None) -> list[dict]:
        from distributed import Client, as_completed   # the dask extra (checked in __init__)
        own = self._client is None
        if own:
            try:
                check_scheduler_listens(str(self.address))
                client = Client(self.address, timeout=f"{self.timeout_s}s")
            except (OSError, TimeoutError, ValueError, MemoryError) as exc:
                # ValueError: not an address (no port); MemoryError: something that is not a
                # Dask scheduler answered on that port (its bytes read as a huge frame size)
                raise UserError(f"cannot reach the Dask scheduler at {self.address}: "
                                f"{exc.__class__.__name__}; start one (dask scheduler) "
                                f"or check the address") from None
        else:
            client = self._client
        try:
            futures = [client.submit(run_task, t, key=f"snan-{i}-{t.seed}", pure=False)
                       for i, t in enumerate(tasks)]
            index = {f.key: i for i, f in enumerate(futures)}
            results: list[dict | None] = [None] * len(tasks)
            bar = track(progress, task, _units(tasks))
            for fut in as_completed(futures):
                i = index[fut.key]
                results[i] = result = fut.result()
                if on_result is not None:
                    on_result(i, result)
                bar.advance(tasks[i].weight)
                fut.release()
            return results  # type: ignore[return-value]
        finally:
            if own:
                client.close()


def make_executor(workers: int | None = None, dask: str | None = None) -> Executor:
    """``dask`` address -> :class:`DaskExecutor`; ``workers == 1`` -> serial; else processes."""
    if dask:
        return DaskExecutor(dask)
    if workers == 1:
        return SerialExecutor()
    return ProcessExecutor(workers)
