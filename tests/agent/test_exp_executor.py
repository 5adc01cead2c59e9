"""Sweeps: seeds from keys (never from order), identical results from every executor
(serial, local processes, a Dask LocalCluster), chunk-size invariance, progress."""

import numpy as np
import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.config import load_config
from snan_hil.host.experiments.common import condition_tasks
from snan_hil.host.experiments.executor import (DaskExecutor, ProcessExecutor, SerialExecutor,
                                                Task, make_executor, seed_tasks, task_seed)
from snan_hil.host.experiments.trials import nav_batch


def _sweep(chunk=3, order=None):
    cfg = load_config(preset="snan-3x3")
    no = cfg.replace(**{"astro.enabled": False})
    tasks = (condition_tasks("t", ("astro",), cfg, {}, 7, chunk)
             + condition_tasks("t", ("none",), no, {}, 7, chunk)
             + condition_tasks("t", ("maze",), cfg, {"walls": 0.25, "goals": 2}, 5, chunk))
    if order is not None:
        tasks = [tasks[i] for i in order]
    return seed_tasks(tasks, 42)


def _by_key(tasks, results):
    return {t.key: r for t, r in zip(tasks, results)}


def test_task_seed_depends_on_master_seed_and_key_only():
    assert task_seed(1, ("a", 0.5, 3)) == task_seed(1, ("a", 0.5, 3))
    assert task_seed(1, ("a", 0.5, 3)) != task_seed(2, ("a", 0.5, 3))
    assert task_seed(1, ("a", 0.5, 3)) != task_seed(1, ("a", 0.5, 4))
    assert 0 <= task_seed(7, ("x",)) < 2 ** 63
    fwd = _sweep()
    rev = _sweep(order=list(range(len(fwd)))[::-1])
    assert {t.key: t.seed for t in fwd} == {t.key: t.seed for t in rev}


def test_duplicate_keys_are_refused():
    t = Task(key=("a", 1), fn=nav_batch, config=None)
    with pytest.raises(ValueError, match="duplicate"):
        seed_tasks([t, Task(key=("a", 1), fn=nav_batch, config=None)], 1)


def test_serial_and_processes_and_order_give_identical_results():
    tasks = _sweep()
    units = []
    serial = SerialExecutor().execute(tasks, progress=units.append, task="sweep")
    assert [e.done for e in units] == [0, *np.cumsum([t.weight for t in tasks])]
    assert {e.task for e in units} == {"sweep"} and units[-1].total == 19
    got = []
    procs = ProcessExecutor(2).execute(tasks, progress=got.append)
    assert got[0].done == 0 and got[-1].done == got[-1].total == 19
    assert np.all(np.diff([e.done for e in got]) > 0)
    assert procs == serial                                # in task order
    rev = _sweep(order=list(range(len(tasks)))[::-1])
    assert _by_key(rev, SerialExecutor().execute(rev)) == _by_key(tasks, serial)


def test_chunk_size_does_not_change_a_condition():
    a = _sweep(chunk=2)
    b = _sweep(chunk=7)
    ra, rb = SerialExecutor().execute(a), SerialExecutor().execute(b)

    def cond(tasks, res, name):
        return [s for t, r in zip(tasks, res) if t.key[1] == name for s in r["steps"]]
    for name in ("astro", "none", "maze"):
        assert cond(a, ra, name) == cond(b, rb, name)
    assert cond(a, ra, "astro") != cond(a, ra, "none")   # the conditions really differ


def test_dask_local_cluster_gives_identical_results():
    distributed = pytest.importorskip("distributed")
    tasks = _sweep()
    serial = SerialExecutor().execute(tasks)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        got = []
        res = DaskExecutor(client=client).execute(tasks, progress=got.append)
    assert res == serial
    assert got[-1].done == got[-1].total == 19


def test_executor_choice_and_bad_values():
    assert isinstance(make_executor(1), SerialExecutor)
    assert isinstance(make_executor(None), ProcessExecutor)
    with pytest.raises(UserError):
        ProcessExecutor(0)
    with pytest.raises(UserError):
        DaskExecutor(None)


def test_unreachable_scheduler_is_a_user_error():
    pytest.importorskip("distributed")
    ex = DaskExecutor("tcp://127.0.0.1:9", timeout_s=1.0)
    with pytest.raises(UserError, match="cannot reach the Dask scheduler"):
        ex.execute(_sweep()[:1])


def test_a_refused_scheduler_port_is_known_without_dasks_retries_and_a_listening_one_passes():
    import socket

    from snan_hil.host.experiments.executor import check_scheduler_listens
    with socket.socket() as listening:
        listening.bind(("127.0.0.1", 0))
        listening.listen()
        port = listening.getsockname()[1]
        check_scheduler_listens(f"tcp://127.0.0.1:{port}")     # something listens: Dask's turn
        check_scheduler_listens(f"inproc://127.0.0.1:{port}")  # not TCP: left to Dask
    with pytest.raises(ConnectionRefusedError):                # closed now: refused at once
        check_scheduler_listens(f"tcp://127.0.0.1:{port}")
    with pytest.raises(UserError, match="at tcp://127.0.0.1:9: ConnectionRefusedError"):
        DaskExecutor("tcp://127.0.0.1:9", timeout_s=60.0).execute(_sweep()[:1])


def _slow_task(config, params, seed):
    """A task that marks its start in ``config`` (a folder) and takes a while."""
    import pathlib
    import time
    pathlib.Path(config, f"started-{params['k']}").touch()
    time.sleep(0.3)
    return {"k": params["k"]}


def test_an_interrupted_process_sweep_stops_at_once(tmp_path):
    # issue 38 item 13: experiment sat ~15 s on a frozen bar after Ctrl-C, the pool running
    # its queued tasks before the command could stop
    tasks = seed_tasks([Task(key=("slow", k), fn=_slow_task, config=str(tmp_path),
                             params={"k": k}) for k in range(24)], 1)
    got = []

    def interrupt(i, result):
        got.append(result)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        ProcessExecutor(2).execute(tasks, on_result=interrupt)
    assert len(got) == 1
    started = len(list(tmp_path.glob("started-*")))
    assert started <= 5, started          # the running ones and the few handed out, not 24
