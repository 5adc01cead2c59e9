"""A restartable job on an emulated chip (lab/runner.py, calibration/bench.py): each unit runs
on its own connection of the board, so the runner can save the chip before the unit and put it
back when the unit was cut; a resumed run then gives what an uninterrupted one gives."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model import CrossbarArray
from snan_hil.host.checkpoint import open_run
from snan_hil.lab.opener import FileUse, plan_board
from snan_hil.lab.ports import BoardAddress
from snan_hil.lab.runner import JobInterrupted, RunOptions, run_job


@dataclass(frozen=True)
class Cell:
    n: int

    @property
    def key(self) -> str:
        return f"cell-{self.n}"

    @property
    def group(self) -> str | None:
        return self.key


class Pulses:
    """Three units, three SET pulses each on cell (n, 0); unit ``cut_at`` is cut (Ctrl-C)
    after its pulses changed the chip. The record: the conductance after each pulse."""

    kind = "pulse"
    restartable = True

    def __init__(self, cut_at: int | None = None) -> None:
        self.cut_at = cut_at
        self.sessions: list[Any] = []

    def describe(self) -> dict[str, Any]:
        return {"units": 3}

    def plan(self, bench: Any) -> list[Cell]:
        self.sessions.append(bench.session)
        return [Cell(n) for n in range(3)]

    def run_unit(self, unit: Cell, bench: Any, ctx: Any) -> dict[str, Any]:
        self.sessions.append(bench.session)
        io = bench.cell(unit.n, 0, stage="cut")
        io.read()
        g = [io.pulse(Polarity.SET, 0.8) for _ in range(3)]
        if unit.n == self.cut_at:
            raise KeyboardInterrupt
        return {"g_s": g}

    def restore(self, unit: Cell, record: dict[str, Any]) -> None:
        pass

    def result(self, records: dict[str, Any], status: str) -> dict[str, Any]:
        return dict(records)

    def summary(self, result: dict[str, Any]) -> dict[str, Any]:
        return {"units": len(result)}


def run(d: Path, job: Pulses, *, resume: bool = False) -> Any:
    folder = open_run(d / "out", "test", {"job": "pulses"}, resume=resume)
    board = plan_board(BoardAddress(f"emu://?state={d / 'chip.npz'}&seed=3"),
                       FileUse(record=True))
    return run_job(job, board, RunOptions(folder=folder)).result


def chip(d: Path) -> np.ndarray:
    return np.asarray(CrossbarArray.load(str(d / "chip.npz")).state)


def test_each_unit_runs_on_its_own_connection(tmp_path):
    job = Pulses()
    run(tmp_path, job)
    planned, *units = job.sessions
    assert len(units) == 3 and len({id(s) for s in job.sessions}) == 4   # a session a unit
    assert not (tmp_path / "out" / "checkpoint" / "boundaries").exists() or not any(
        (tmp_path / "out" / "checkpoint" / "boundaries").iterdir())     # dropped once done


def test_a_cut_unit_runs_again_from_the_chip_saved_before_it(tmp_path):
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    for d in (whole, cut):
        d.mkdir()
    reference = run(whole, Pulses())
    with pytest.raises(JobInterrupted) as stop:
        run(cut, Pulses(cut_at=1))
    assert list(stop.value.run.result) == ["cell-0"]       # what finished before the cut
    assert (cut / "out" / "checkpoint" / "boundaries" / "before-cell-1" / "saved").is_file()
    assert not np.array_equal(chip(cut), chip(whole))      # the cut unit's pulses are on it
    resumed = run(cut, Pulses(), resume=True)
    assert resumed == reference                            # conductances read, pulse by pulse
    assert np.array_equal(chip(cut), chip(whole))


def test_a_run_cut_right_after_a_unit_is_committed_resumes_alike(tmp_path, monkeypatch):
    """The next unit's chip is saved before a unit is committed: a run that dies between
    the commit and the next unit leaves its boundary, so the resumed run's own connection
    (one more boot of the emulated chip, its read noise drawn anew) does not show."""
    from snan_hil.host.checkpoint import RunFolder
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    for d in (whole, cut):
        d.mkdir()
    reference = run(whole, Pulses())
    commit = RunFolder.commit

    def commit_then_die(self: RunFolder, unit: str, data: Any) -> None:
        commit(self, unit, data)
        if unit == "cell-0":
            raise KeyboardInterrupt
    monkeypatch.setattr(RunFolder, "commit", commit_then_die)
    with pytest.raises(JobInterrupted):
        run(cut, Pulses())
    monkeypatch.undo()
    assert run(cut, Pulses(), resume=True) == reference
    assert np.array_equal(chip(cut), chip(whole))
