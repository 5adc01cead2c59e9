"""``compare`` as one document stream: a ``launches`` event per launch (scenario, set, steps,
path, success, the calcium of every grid cell), consumed by the history (its documents
export validates with Bluesky's event-model schemas), by compare.json (the run block) and by
``snan-hil watch`` (the grid, path, calcium and running medians per scenario, live and in
replay, driven headless with Textual's pilot)."""

from __future__ import annotations

import asyncio
import csv
import json
import statistics

import pytest
from event_model import DocumentNames, schema_validators

from snan_hil.records import history as H
from snan_hil.tools import cli
from snan_hil.tools.watch_app import WatchApp
from snan_hil.tools.watch_state import HistorySource, ReplaySource

SHORT = ["--set", "grid.max_steps=15"]
SCEN = ("sw_astro", "hw_astro")


@pytest.fixture(scope="module")
def compared(cli_trained, tmp_path_factory):
    """One reduced compare on the emulator (1 set, 2 launches, a software and a hardware
    scenario), its output folder and its history database."""
    home = tmp_path_factory.mktemp("compare-stream")
    mp = pytest.MonkeyPatch()
    mp.setenv("SNAN_HIL_EMU_STATE", str(home / "chip.npz"))
    mp.setenv("XDG_DATA_HOME", str(home / "data"))
    mp.delenv("SNAN_HIL_PORT", raising=False)
    out = home / "res"
    try:
        assert cli.main(["compare", "--weights", str(cli_trained), "--port", "emu", "--out",
                         str(out), "--sets", "1", "--launches", "2", "--seed", "4",
                         "--scenarios", ",".join(SCEN), "--no-figure", "--json",
                         "--sample", "wafer 3", *SHORT]) == 0
    finally:
        mp.undo()
    return home, out


def _docs(home, out=None):
    """The fixture's compare run (by the uid its compare.json records) and its documents."""
    uid = json.loads(((out or home / "res") / "compare.json").read_text())["run"]["uid"]
    with H.History.open(home / "chip.history.sqlite", create=False) as db:
        run = db.run(uid)
        return run, [(n, d) for _i, n, d in db.documents(run.id)]


def test_compare_emits_every_launch_with_path_and_calcium(compared):
    home, out = compared
    run, docs = _docs(home)
    assert run.kind == "hil" and run.sample == "wafer 3" and run.status == "complete"
    desc = [d for n, d in docs if n == "descriptor" and d["name"] == "launches"]
    assert len(desc) == 1
    keys = desc[0]["data_keys"]
    assert keys["calcium_final"]["dtype"] == "array" and keys["steps"]["dtype"] == "integer"
    events = [d["data"] for n, d in docs if n == "event" and d["descriptor"] == desc[0]["uid"]]
    rows = list(csv.DictReader((out / "launches.csv").open()))
    assert len(events) == len(rows) == 2 * len(SCEN)
    for e in events:                         # each event is the launch the CSV records
        [row] = [r for r in rows if r["scenario"] == e["scenario"]
                 and int(r["launch"]) == e["launch"]]
        assert e["steps"] == int(row["steps"]) and str(e["success"]) == row["success"]
        assert e["path"][0] == 18 and len(e["path"]) == e["steps"] + 1
        assert len(e["calcium_final"]) == 36 and max(e["calcium_final"]) > 0
        assert (e["grid_rows"], e["grid_cols"]) == (6, 6)
    # the programming pulses are in the same run, and the stop carries the medians
    stop = [d for n, d in docs if n == "stop"][0]
    assert stop["num_events"]["launches"] == 4 and stop["num_events"]["pulses"] == run.pulses
    res = json.loads((out / "compare.json").read_text())
    for s in SCEN:
        ok = [e["steps"] for e in events if e["scenario"] == s and e["success"]]
        want = float(statistics.median(ok)) if ok else None
        assert stop["summary"]["scenarios"][s]["median_steps"] == want == \
            res["scenarios"][s]["median_steps"]
    assert res["run"]["uid"] == run.uid and res["run"]["history_run_id"] == run.id


def test_compare_documents_export_validates(compared, capsys, monkeypatch, tmp_path):
    home, _out = compared
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(home / "chip.npz"))
    target = tmp_path / "docs.jsonl"
    assert cli.main(["history", "--export", "documents", "-o", str(target), "--port",
                     "emu"]) == 0
    docs = [json.loads(line) for line in target.read_text().splitlines()]
    for name, doc in docs:
        schema_validators[DocumentNames[name]].validate(doc)
    run, _d = _docs(home)
    [start] = [d for n, d in docs if n == "start" and d["uid"] == run.uid]
    assert start["plan_name"] == "hil" and start["sample"] == "wafer 3"
    assert sum(1 for n, d in docs if n == "event" and "calcium_final" in d["data"]) >= 4


def _hil_text(app):
    return app.query_one("#hil").render()


def test_watch_shows_a_compare_live_and_in_replay(compared):
    home, _out = compared
    _run, docs = _docs(home)
    events = [d["data"] for n, d in docs if n == "event" and "calcium_final" in d["data"]]
    last = events[-1]
    # live: the documents come in as the run wrote them (cut after the first launch)
    first_launch = next(i for i, (n, d) in enumerate(docs)
                        if n == "event" and "calcium_final" in d["data"])
    source = ReplaySource(docs[:first_launch + 1])
    app = WatchApp(source, poll_s=60)

    async def drive():
        async with app.run_test(size=(130, 44)) as pilot:
            await pilot.pause()
            early = app.view.medians()
            source.docs = docs                     # the rest of the run arrives
            app.refresh_view()
            await pilot.pause()
            shown = app.export_screenshot().replace("&#160;", " ")
            return early, app.view.medians(), shown, app.query_one("#hil").display
    early, final, shown, displayed = asyncio.run(drive())
    assert displayed and list(early) == [events[0]["scenario"]]
    for s in SCEN:
        ok = [e["steps"] for e in events if e["scenario"] == s and e["success"]]
        assert final[s] == (float(statistics.median(ok)) if ok else None, len(ok), 2)
    title = f"{last['scenario']} launch {last['launch']}: {last['steps']} steps"
    assert title in shown and "running medians" in shown
    # replay of the finished run from the history: the same view
    followed = HistorySource(home / "chip.history.sqlite")
    replay = WatchApp(ReplaySource(followed.poll()), poll_s=60)
    followed.close()

    async def replayed():
        async with replay.run_test(size=(130, 44)) as pilot:
            await pilot.pause()
            return replay.view.medians(), replay.export_screenshot().replace("&#160;", " ")
    medians, svg = asyncio.run(replayed())
    assert medians == final and title in svg


def test_the_grid_names_the_set_when_a_run_launches_several():
    from snan_hil.records.documents import DocumentCollector, RunPublisher
    from snan_hil.tools.watch_app import hil_grid
    from snan_hil.tools.watch_state import RunView
    pub = RunPublisher(kind="hil")
    col = DocumentCollector()
    pub.subscribe(col)
    for k in (0, 1):
        pub.event("launches", {"scenario": "hw_astro", "set_index": k, "launch": 0,
                               "steps": 5, "success": True, "path": [18, 12, 6, 0, 1, 0],
                               "calcium_final": [0.1] * 36, "grid_rows": 6, "grid_cols": 6,
                               "ca_thr": 0.2})
    view = RunView()
    view.feed(col.docs)
    assert view.sets == [0, 1] and hil_grid(view).plain.startswith("hw_astro set 1 launch 0")


def test_a_software_compare_is_a_run_of_the_runs_database(cli_trained, emu, capsys):
    assert cli.main(["compare", "--weights", str(cli_trained), "--out", str(emu / "sw"),
                     "--sets", "1", "--launches", "2", "--scenarios", "sw_noastro",
                     "--no-figure", "--json", *SHORT]) == 0
    uid = json.loads(capsys.readouterr().out)["run"]["uid"]
    with H.History.open(emu / "data" / "snan-hil" / "runs.history.sqlite", create=False) as db:
        run = db.run(uid)
        docs = [(n, d) for _i, n, d in db.documents(run.id)]
    assert run.kind == "hil" and run.status == "complete"
    assert sum(1 for n, d in docs if n == "event" and "calcium_final" in d["data"]) == 2


def test_a_stop_ends_a_compare_between_two_launches(compared, cli_trained, capsys, monkeypatch,
                                                    stop_after):
    """The chip holds the fixture's set: launched again without programming, stopped from
    the control channel once the first launch is recorded."""
    home, _out = compared
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(home / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(home / "data"))
    stop_after("launches", 1)
    out = home / "stopped"
    assert cli.main(["compare", "--weights", str(cli_trained), "--port", "emu",
                     "--out", str(out), "--sets", "1", "--launches", "4", "--seed", "4",
                     "--scenarios", "hw_astro", "--no-program", "--no-figure", *SHORT]) == 130
    assert "stop requested" in capsys.readouterr().err
    with H.History.open(home / "chip.history.sqlite", create=False) as db:
        run = db.runs(limit=1)[0]
        docs = [(n, d) for _i, n, d in db.documents(run.id)]
    stop = [d for n, d in docs if n == "stop"][0]
    assert run.status == "interrupted" and stop["exit_status"] == "abort"
    assert stop["num_events"]["launches"] == 1 and not (out / "compare.json").exists()


def test_a_software_compare_refuses_a_history_file_not_ours(cli_trained, emu, one_line):
    (emu / "notes.sqlite").write_text("hello\n")
    assert cli.main(["compare", "--weights", str(cli_trained), "--out", str(emu / "sw"),
                     "--scenarios", "sw_astro", "--history", str(emu / "notes.sqlite"),
                     *SHORT]) == 2
    assert "not a snan-hil history database" in one_line()
    assert not (emu / "sw").exists()                      # refused before any launch
