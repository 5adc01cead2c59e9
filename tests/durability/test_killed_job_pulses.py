"""A board job killed with SIGKILL leaves its pulse journal, and the next job on that board
records the killed run's pulses its recorder had not written yet (issue 32: the interrupted
job's pulses reconciled with the history for every job, programming included).

``program-weights`` records a cell's pulses with the cell's result (one transaction per cell),
so a kill in the middle of a cell leaves pulses the board applied and the history lacks; the
journal (written before each pulse is sent and after its reply) has them. The next command
on the board (here ``read-cell``, which sends no pulse) records them into the killed run
(stage ``recovered``) before its own work: the killed run's history pulses then equal the
journal's done pulses, and -- where the board's pulse counter outlives the host, an emulator
served on a socket -- the board's counter agrees (a pulse sent but not answered when the host
died may have run: at most the journal's ``sent`` ones).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from snan_hil.calibration.testing import grid_weights
from snan_hil.lab.runner import RECOVERED_STAGE, journal_dir
from snan_hil.records.history import History
from snan_hil.records.journal import read_journal
from snan_hil.tools import cli

PY = [sys.executable, "-m", "snan_hil.tools.cli"]

DONE_BEFORE_KILL = 40
"""Pulses the journal shows done before the host is killed (a few cells into the run)."""


def _journal(history):
    """The one journal beside ``history`` (None before the run wrote its first line)."""
    files = sorted(journal_dir(history).glob("*.jsonl")) if journal_dir(history).is_dir() \
        else []
    assert len(files) <= 1, files
    return files[0] if files else None


def _recorded(history, uid):
    """(status, pulses recorded, recovered pulses) of run ``uid``."""
    with History.open(history, create=False) as db:
        run = db.run(uid)
        recovered = db.conn.execute("SELECT count(*) FROM pulses WHERE run_id = ? AND stage = ?",
                                    (run.id, RECOVERED_STAGE)).fetchone()[0]
    return run.status, run.pulses, recovered


def _program_and_kill(d, port, history, env):
    """Start program-weights of a 6x6 grid (120 synapses), SIGKILL it once its journal shows
    :data:`DONE_BEFORE_KILL` pulses done; (journal path, its account, the killed run's
    uid)."""
    np.save(d / "w.npy", grid_weights(6, 6, seed=4))
    host = subprocess.Popen([*PY, "program-weights", str(d / "w.npy"), "--port", port,
                             "--timeout", "5", "--layout", str(d / "l.json"), "--report",
                             str(d / "r.json"), "--history", str(history)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 300
        done = 0
        while done < DONE_BEFORE_KILL:
            assert host.poll() is None, "programming ended before the kill: " + \
                host.stderr.read()
            assert time.monotonic() < deadline
            time.sleep(0.02)
            path = _journal(history)
            got = read_journal(path) if path is not None else None
            done = sum(p.state == "done" for p in got.pulses) if got is not None else 0
        host.send_signal(signal.SIGKILL)
        host.wait(timeout=20)
        assert host.returncode == -signal.SIGKILL
    finally:
        if host.poll() is None:
            host.kill()
            host.wait(timeout=20)
    host.communicate(timeout=60)
    path = _journal(history)
    assert path is not None, "the killed run left no journal"
    account = read_journal(path)
    [uid] = account.runs()
    return path, account, uid


@pytest.mark.parametrize("where", ["server", "inprocess"])
def test_a_killed_program_weights_pulses_are_recorded_by_the_next_command(
        tmp_path, where, start_emu_server, capsys, monkeypatch):
    # A kill between a cell's result and its next pulse leaves nothing unrecorded (the
    # journal and the history agree already): then the run is repeated on a fresh chip (at
    # most 6 tries: on a loaded machine the killer polls late and lands between cells more
    # often), so what is checked is a kill that left pulses to reconcile.
    for attempt in range(6):
        d = tmp_path / f"try{attempt}"
        d.mkdir()
        env = dict(os.environ, XDG_DATA_HOME=str(d / "xdg"),
                   SNAN_HIL_EMU_STATE=str(d / "c.npz"))
        for key in ("XDG_DATA_HOME", "SNAN_HIL_EMU_STATE"):
            monkeypatch.setenv(key, env[key])
        history = d / "h.sqlite"
        server, port = start_emu_server(d / "c.npz", env=env) if where == "server" \
            else (None, "emu")
        try:
            path, account, uid = _program_and_kill(d, port, history, env)
            done = [p for p in account.of_run(uid) if p.state == "done"]
            status, before, recovered = _recorded(history, uid)
            if before < len(done):
                _check_the_next_command(history, port, path, account, uid, server is not None,
                                        capsys)
                return
        finally:
            if server is not None:
                server.kill()
                server.wait(timeout=20)
    pytest.fail("every kill landed between two cells: nothing was left to reconcile")


def _check_the_next_command(history, port, path, account, uid, counter, capsys):
    done = [p for p in account.of_run(uid) if p.state == "done"]
    uncertain = [p for p in account.of_run(uid) if p.state == "sent"]
    assert len(done) >= DONE_BEFORE_KILL and len(uncertain) <= 1
    status, before, recovered = _recorded(history, uid)
    assert status == "crashed" and recovered == 0 and before < len(done)
    capsys.readouterr()
    # the next command on the board: no pulse of its own
    assert cli.main(["read-cell", "--cell", "31,7", "--port", port, "--history",
                     str(history)]) == 0
    err = capsys.readouterr().err
    status, after, recovered = _recorded(history, uid)
    assert after == len(done) and recovered == len(done) - before, (before, after, len(done))
    assert f"recorded {recovered} pulse(s) that a killed run had applied" in err
    assert not path.exists() and not journal_dir(history).exists()
    if counter:                       # the board's pulse counter outlived the host
        assert cli.main(["info", "--port", port, "--json"]) == 0
        status_reply = json.loads(capsys.readouterr().out)["status"]
        ran = status_reply["pulses_applied"] - account.baselines[uid]
        assert len(done) <= ran <= len(done) + len(uncertain), (ran, len(done))
