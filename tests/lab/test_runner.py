"""The job runner (lab/runner.py): the run recorded, the pulse journal reconciled with the
history after a kill, a stop between units with the partial result, a resumed run taking the
committed units, the one write limit of the bench."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from snan_hil.calibration.tickets import PulseTicket, PulseTicketJob
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.host.checkpoint import open_run
from snan_hil.lab.opener import FileUse, plan_board
from snan_hil.lab.ports import BoardAddress
from snan_hil.lab.runner import JobInterrupted, RunOptions, journal_dir, run_job
from snan_hil.records.history import History
from snan_hil.records.journal import read_journal


def board(tmp_path: Path, **address: Any):
    return plan_board(BoardAddress(f"emu://?state={tmp_path / 'chip.npz'}&seed=3", **address),
                      FileUse(record=True))


def history_of(tmp_path: Path) -> Path:
    from snan_hil.board.files import BoardFiles
    path = BoardFiles.beside_chip(tmp_path / "chip.npz").history
    assert path is not None
    return path


@dataclass(frozen=True)
class Step:
    n: int

    @property
    def key(self) -> str:
        return f"step-{self.n}"

    group = None


class Steps:
    """Three units, one SET pulse each on cell (n, 0); the record: the conductance after."""

    kind = "pulse"
    restartable = False

    def __init__(self) -> None:
        self.restored: list[str] = []

    def describe(self) -> dict[str, Any]:
        return {"steps": 3}

    def plan(self, bench: Any) -> list[Step]:
        return [Step(n) for n in range(3)]

    def run_unit(self, unit: Step, bench: Any, ctx: Any) -> dict[str, Any]:
        io = bench.cell(unit.n, 0, stage="steps")
        io.read()
        return {"g_s": io.pulse(Polarity.SET, 0.8)}

    def restore(self, unit: Step, record: dict[str, Any]) -> None:
        self.restored.append(unit.key)

    def result(self, records: dict[str, Any], status: str) -> dict[str, Any]:
        return {"status": status, "units": list(records)}

    def summary(self, result: dict[str, Any]) -> dict[str, Any]:
        return result


def test_a_job_is_recorded_with_its_pulses_and_leaves_no_journal(tmp_path):
    done = run_job(Steps(), board(tmp_path))
    assert done.status == "complete" and done.result["units"] == ["step-0", "step-1", "step-2"]
    with History.open(history_of(tmp_path), create=False) as db:
        [run] = db.runs()
        assert (run.kind, run.status, run.pulses, run.uid) == ("pulse", "complete", 3,
                                                               done.metadata.uid)
    assert not journal_dir(history_of(tmp_path)).exists()


def test_a_stop_between_units_ends_the_run_with_the_finished_units(tmp_path):
    class StopAfterOne(Steps):
        def run_unit(self, unit: Step, bench: Any, ctx: Any) -> dict[str, Any]:
            out = super().run_unit(unit, bench, ctx)
            with History.open(history_of(tmp_path)) as db:      # as snan-hil watch writes it
                db.request_control(ctx_uid[0], "stop", "test")
            return out
    ctx_uid: list[str] = []
    from snan_hil.records.documents import RunMetadata
    meta = RunMetadata()
    ctx_uid.append(meta.uid)
    with pytest.raises(JobInterrupted) as stop:
        run_job(StopAfterOne(), board(tmp_path), RunOptions(metadata=meta))
    assert stop.value.run.status == "interrupted"
    assert stop.value.run.result == {"status": "interrupted", "units": ["step-0"]}
    with History.open(history_of(tmp_path), create=False) as db:
        [run] = db.runs()
        assert (run.status, run.pulses) == ("interrupted", 1)


def test_a_resumed_run_takes_the_committed_units_and_runs_the_rest(tmp_path):
    folder = open_run(tmp_path / "out", "steps", {"t": 1}, resume=False)
    folder.commit("step-0", {"g_s": 1e-4})
    job = Steps()
    done = run_job(job, board(tmp_path), RunOptions(folder=folder))
    assert job.restored == ["step-0"]
    assert sorted(p.name for p in folder.dir.glob("unit-*.json")) == [
        "unit-step-0.json", "unit-step-1.json", "unit-step-2.json"]
    with History.open(history_of(tmp_path), create=False) as db:
        assert db.runs()[0].pulses == 2                       # step-0 was not run again
    # the run's journal is in the checkpoint, naming each pulse's unit
    got = read_journal(folder.path("pulses.jsonl"))
    assert [(p.unit, p.state) for p in got.pulses] == [("step-1", "done"), ("step-2", "done")]
    assert done.result["units"] == ["step-0", "step-1", "step-2"]


KILLED = textwrap.dedent("""
    import os, sys
    from snan_hil.records import history
    history.FLUSH_INTERVAL_S = 1e9          # the recorder's buffer is never written ...
    from snan_hil.calibration.tickets import PulseTicket, PulseTicketJob
    from snan_hil.common.polarity import Polarity
    from snan_hil.lab.opener import FileUse, plan_board
    from snan_hil.lab.ports import BoardAddress
    from snan_hil.lab.runner import RunOptions, run_job

    class Killer:                           # ... when the process dies after 5 pulses
        n = 0
        def on_pulses(self, events):
            Killer.n += len(events)
            if Killer.n == 5:
                os._exit(9)
        def on_cell(self, event):
            pass

    plan = plan_board(BoardAddress(sys.argv[1]), FileUse(record=True))
    job = PulseTicketJob(PulseTicket(2, 3, Polarity.SET, (0.4,), count=50))
    run_job(job, plan, RunOptions(observers=(Killer(),)))
""")


def test_a_killed_runs_pulses_are_recorded_from_its_journal_by_the_next_run(tmp_path):
    port = f"emu://?state={tmp_path / 'chip.npz'}&seed=3"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    killed = subprocess.run([sys.executable, "-c", KILLED, port], env=env, timeout=120)
    assert killed.returncode == 9
    history = history_of(tmp_path)
    [journal] = list(journal_dir(history).glob("*.jsonl"))
    assert [p.state for p in read_journal(journal).pulses] == ["done"] * 5
    with History.open(history, create=False) as db:
        [run] = db.runs()
        assert (run.status, run.pulses) == ("crashed", 0)      # the buffer died with it
    done = run_job(PulseTicketJob(PulseTicket(0, 0, Polarity.SET, (0.4,))), board(tmp_path))
    assert done.recovered == 5
    with History.open(history, create=False) as db:
        killed_run = db.run(run.id)
        assert killed_run is not None and killed_run.pulses == 5
        stages = {r[0] for r in db.conn.execute(
            "SELECT stage FROM pulses WHERE run_id = ?", (run.id,))}
        assert stages == {"recovered"}
    assert not journal.exists()


def test_a_job_amplitude_above_the_one_limit_is_one_line_before_a_pulse(tmp_path):
    job = PulseTicketJob(PulseTicket(1, 1, Polarity.SET, (1.2,)))
    with pytest.raises(UserError, match=r"above the host's write limit 1 V"):
        run_job(job, board(tmp_path, max_write_v=1.0))
    assert not history_of(tmp_path).exists()            # refused before the run began
