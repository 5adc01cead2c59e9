"""The comparison as a board job (host/hil/compare.py ``CompareJob``) and one scenario as a
board job (host/hil/scenario.py ``ScenarioJob``): the comparison's results come from its
units' records alone (what a run over several boards gets back from its workers), each set
runs on its own connection of the board, and a notebook's scenario is recorded in the chip's
history like ``snan-hil run``'s."""

from __future__ import annotations

import json

import pytest

from snan_hil.host.hil.compare import (CompareJob, CompareRequest, GeometryUnit, SetUnit,
                                       without_wall_times)
from snan_hil.host.hil.config import load_hil_config
from snan_hil.records import history as H
from snan_hil.tools import cli

SHORT = ["--set", "grid.max_steps=15"]
SCEN = ("sw_astro", "hw_astro")


@pytest.fixture(scope="module")
def compared(cli_trained, tmp_path_factory):
    """Two sets, 2 launches, a software and a hardware scenario on a fresh emulated chip."""
    home = tmp_path_factory.mktemp("compare-job")
    mp = pytest.MonkeyPatch()
    mp.setenv("SNAN_HIL_EMU_STATE", str(home / "chip.npz"))
    mp.setenv("XDG_DATA_HOME", str(home / "data"))
    mp.delenv("SNAN_HIL_PORT", raising=False)
    try:
        assert cli.main(["compare", "--weights", str(cli_trained), "--port", "emu", "--out",
                         str(home / "res"), "--launches", "2", "--seed", "4", "--scenarios",
                         ",".join(SCEN), "--no-figure", "--json", *SHORT]) == 0
    finally:
        mp.undo()
    return home


def job_of(cli_trained) -> CompareJob:
    hil = load_hil_config(None, [SHORT[1]])
    return CompareJob(CompareRequest(str(cli_trained), hil, launches=2, seed=4, scenarios=SCEN))


def test_the_results_come_from_the_units_records_alone(compared, cli_trained):
    cp = compared / "res" / "checkpoint"
    records = {key: json.loads((cp / f"unit-{key}.json").read_text())["data"]
               for key in ("set-0", "set-1", "geometry")}
    job = job_of(cli_trained)                       # a new job: never planned, never run
    assert job.unit_order() == ["set-0", "set-1", "geometry"] == job.groups()
    got = job.result(records, "complete")
    want = json.loads((compared / "res" / "compare.json").read_text())
    for key in ("port", "protocol", "mode", "baud", "board", "programming"):
        assert got[key] == want[key], key
    assert got["session"]["identity"] == want["session"]["identity"]
    strip = ("run", "trained_config_check", "files")
    assert without_wall_times(got) == {k: v for k, v in without_wall_times(want).items()
                                       if k not in strip}
    partial = job.result({"set-0": records["set-0"]}, "interrupted")
    assert partial["sets"] == [0]                  # an interrupted run: what finished
    with pytest.raises(RuntimeError, match="set 1"):
        job.result({"set-0": records["set-0"]}, "complete")


def test_each_set_ran_on_its_own_connection_and_the_units_are_sets(compared, cli_trained):
    cp = compared / "res" / "checkpoint"
    sets = [json.loads((cp / f"unit-set-{k}.json").read_text())["data"] for k in (0, 1)]
    boots = [s["session"]["identity"]["board_id"] for s in sets]
    assert boots[0] == boots[1]                     # one chip
    assert all(s["programming"]["all_ok"] for s in sets)
    assert [SetUnit(0).key, SetUnit(0).group, GeometryUnit().group] == \
        ["set-0", "set-0", "geometry"]
    assert not any((cp / "boundaries").glob("*/saved"))      # every boundary dropped
    with H.History.open(compared / "chip.history.sqlite", create=False) as db:
        assert any(r.status == "complete" and r.config["mode"] == "on_board"
                   and r.config["sets"] is None for r in db.runs(kind="hil"))


def test_a_notebook_scenario_is_a_recorded_run_with_its_launches(compared, cli_trained):
    import snan_hil
    chip = compared / "chip.npz"
    with snan_hil.open_board(f"emu://?state={chip}", progress=False) as board:
        run = board.run_scenario("hw_astro", cli_trained, weight_set=1, launches=2, seed=4,
                                 overrides=(SHORT[1],))
        uid = board.last_run.metadata.uid
    assert run.success.shape == (2,) and run.board_us_per_decision is not None
    with H.History.open(compared / "chip.history.sqlite", create=False) as db:
        row = db.run(uid)
        docs = [d for _i, n, d in db.documents(row.id) if n == "event"]
    assert row.kind == "hil" and row.status == "complete"
    assert sum(1 for d in docs if "calcium_final" in d["data"]) == 2
