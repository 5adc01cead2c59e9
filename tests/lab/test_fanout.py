"""The one scheduling loop of every job over several boards (lab/fanout.py): groups placed on
boards, each board's worker running the same unit loop as one board, replicated jobs, a user
mistake in a group, a lost board's group moved, a stop from the run's control channel."""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cloudpickle
import pytest

from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.host.checkpoint import open_run
from snan_hil.lab.boards import LinkOptions, RunLink, local_boards
from snan_hil.lab.fanout import PLACEMENT_FILE, BoardSet, run_group, run_on_boards
from snan_hil.lab.opener import FileUse
from snan_hil.lab.runner import RunOptions
from snan_hil.records.control import StopRequested
from snan_hil.records.history import History

pytest.importorskip("distributed")


def emu(path: Path) -> str:
    return f"emu://?state={path}&seed=3"


@dataclass(frozen=True)
class Cycle:
    group: str
    n: int

    @property
    def key(self) -> str:
        return f"g{self.group}-c{self.n}"


class ToyJob:
    """Two units a group; each unit applies one SET pulse to cell (group, n) of its board and
    records the board it ran on and the conductance after."""

    kind = "pulse"
    restartable = False

    def __init__(self, groups: tuple[str, ...] = ("0", "1", "2"), fail: str | None = None):
        self._groups, self.fail = groups, fail

    def groups(self) -> tuple[str, ...]:
        return self._groups

    def unit_order(self) -> list[str]:
        return [Cycle(g, n).key for g in self._groups for n in (0, 1)]

    def describe(self) -> dict[str, Any]:
        return {"groups": list(self._groups)}

    def plan(self, bench: Any) -> list[Cycle]:
        return [Cycle(g, n) for g in self._groups for n in (0, 1)]

    def run_unit(self, unit: Cycle, bench: Any, ctx: Any) -> dict[str, Any]:
        if self.fail == unit.group:
            raise UserError(f"group {unit.group} asks for 9 V; lower it")
        io = bench.cell(int(unit.group), unit.n, stage="toy")
        io.read()
        g = io.pulse(Polarity.SET, 0.8)
        ctx.emit("progress", {"task": unit.key, "done": 1, "total": 1,
                              "detail": f"board {ctx.board}", "note": ""})
        return {"board": ctx.board, "g_s": g}

    def restore(self, unit: Cycle, record: dict[str, Any]) -> None:
        pass

    def result(self, records: dict[str, Any], status: str) -> dict[str, Any]:
        return dict(records)

    def summary(self, result: dict[str, Any]) -> dict[str, Any]:
        return {"units": len(result)}


class EverywhereJob(ToyJob):
    """No groups: the whole job on every board's own chip."""

    groups = None  # type: ignore[assignment]


def dies_on_board_1(job: Any, task: Any, after: Any = None) -> dict[str, Any]:
    import snan_hil.lab.boards as boards
    if boards._plugin().index == 1:
        os._exit(3)                                 # this worker process ends here
    return run_group(job, task, after)


cloudpickle.register_pickle_by_value(sys.modules[__name__])


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    d = tmp_path_factory.mktemp("fanout")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XDG_DATA_HOME", str(d / "xdg"))
        with local_boards([emu(d / "w0.npz"), emu(d / "w1.npz")], allowed_failures=0) as c:
            yield c


def boards(tmp_path: Path, *, reassign: bool = False) -> BoardSet:
    ports = (emu(tmp_path / "a.npz"), emu(tmp_path / "b.npz"))
    return BoardSet(ports, None, LinkOptions(), FileUse(record=True), reassign=reassign)


def _run(cluster, tmp_path, job, *, reassign=False, task=run_group, folder=None, **kw):
    """The job over the shared cluster's two workers, on the chips of ``boards``."""
    bs = boards(tmp_path, reassign=reassign)
    cluster.wait_for_workers(2)                 # a killed worker is back (its nanny)
    return run_on_boards(job, bs, RunOptions(folder=folder), task=task, client=cluster,
                         **kw)


def _history(tmp_path: Path, name: str) -> Path:
    from snan_hil.board.files import BoardFiles
    path = BoardFiles.beside_chip(tmp_path / f"{name}.npz").history
    assert path is not None
    return path


def test_groups_run_on_their_boards_each_board_recording_its_pulses(cluster, tmp_path):
    events: list[tuple[str, dict]] = []
    got = _run(cluster, tmp_path, ToyJob(), emit=lambda s, d: events.append((s, d)))
    assert {k: v["board"] for k, v in got.result.items()} == {
        "g0-c0": 0, "g0-c1": 0, "g1-c0": 1, "g1-c1": 1, "g2-c0": 0, "g2-c1": 0}
    assert {g: u["board"] for g, u in got.units.items()} == {"0": 0, "1": 1, "2": 0}
    # every unit's event came back to the host's stream
    assert sorted(d["task"] for s, d in events if s == "progress") == sorted(got.result)
    for name, n in (("a", 4), ("b", 2)):
        with History.open(_history(tmp_path, name), create=False) as db:
            assert sum(r.pulses for r in db.runs()) == n        # one pulse a unit
    assert [b["lost"] for b in got.boards] == [None, None]


def test_a_job_without_groups_runs_whole_on_every_board(cluster, tmp_path):
    got = _run(cluster, tmp_path, EverywhereJob(("0",)))
    assert got.result is None
    assert [r.board for r in got.per_board] == [0, 1]
    for r in got.per_board:
        assert set(r.records) == {"g0-c0", "g0-c1"}
        assert {v["board"] for v in r.records.values()} == {r.board}


def test_a_user_mistake_in_a_group_is_one_line_and_the_board_is_kept(cluster, tmp_path):
    with pytest.raises(UserError) as caught:
        _run(cluster, tmp_path, ToyJob(fail="1"), reassign=True)
    text = str(caught.value)
    assert text.startswith("group 1 on board 1: group 1 asks for 9 V") and "\n" not in text
    assert "lost" not in text


def test_a_lost_boards_group_moves_and_the_move_is_kept_for_a_resume(cluster, tmp_path):
    folder = open_run(tmp_path / "out", "toy", {"t": 1}, resume=False)
    got = _run(cluster, tmp_path, ToyJob(), reassign=True, task=dies_on_board_1,
               folder=folder)
    assert {g: u["board"] for g, u in got.units.items()} == {"0": 0, "1": 0, "2": 0}
    assert [b["board"] for b in got.boards if b["lost"]] == [1]
    placed = json.loads(folder.path(PLACEMENT_FILE).read_text())
    assert placed == {"1": 0}
    # every unit committed to the checkpoint by the workers
    assert sorted(p.name for p in folder.dir.glob("unit-*.json")) == sorted(
        f"unit-{k}.json" for k in got.result)


def test_without_reassign_a_lost_board_stops_the_run_in_one_line(cluster, tmp_path):
    with pytest.raises(UserError, match=r"board 1 .* was lost .*--resume"):
        _run(cluster, tmp_path, ToyJob(), task=dies_on_board_1)


def test_a_stop_in_the_runs_control_channel_reaches_every_board(cluster, tmp_path):
    db = tmp_path / "runs.sqlite"
    with History.open(db) as h:
        h.request_control("run-1", "stop", "test")
    with pytest.raises(StopRequested):
        _run(cluster, tmp_path, ToyJob(), link=RunLink(history=str(db), uid="run-1"))
    for name in ("a", "b"):
        path = _history(tmp_path, name)
        if path.exists():
            with History.open(path, create=False) as h:
                assert sum(r.pulses for r in h.runs()) == 0     # stopped before a pulse
