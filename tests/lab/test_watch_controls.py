"""The long board jobs that used to ignore the watch controls (map, characterize; mac and
retention share the same wiring) stop through the control channel: the stop request is
written into the history database while the job runs -- as ``snan-hil watch`` writes it --
and the job ends before its next read or pulse, every pulse it sent recorded whole, the run
recorded as interrupted with an ``abort`` stop document."""

from __future__ import annotations

from snan_hil.records import history as H
from snan_hil.tools import cli



def _the_run(emu, kind):
    with H.History.open(emu / "chip.history.sqlite", create=False) as db:
        [run] = db.runs(kind=kind)
        docs = [(n, d) for _i, n, d in db.documents(run.id)]
        pulses = db.conn.execute("SELECT count(*), count(g_after_s) FROM pulses WHERE "
                                 "run_id = ?", (run.id,)).fetchone()
    stop = [d for n, d in docs if n == "stop"]
    return run, stop[0], docs, pulses


def test_a_stop_ends_a_map_between_two_reads(emu, capsys, stop_after):
    stop_after("progress", 1)
    assert cli.main(["map", "--port", "emu"]) == 130
    assert "stop requested" in capsys.readouterr().err
    run, stop, docs, _p = _the_run(emu, "map")
    assert run.status == "interrupted"
    assert stop["exit_status"] == "abort" and "stop requested" in stop["reason"]
    actions = [d["data"].get("action") for n, d in docs if n == "event"]
    assert "stop" in actions
    # no cell result of a map cut short, and the progress shows it stopped early
    assert "cells" not in stop["num_events"]
    done = [d["data"]["done"] for n, d in docs if n == "event" and "task" in d["data"]]
    assert max(done) < 256


def test_a_stop_ends_characterize_between_pulses_each_recorded_whole(emu, capsys,
                                                                     stop_after):
    stop_after("cells", 1)          # asked while the first cell is reported
    assert cli.main(["characterize", "--port", "emu", "--cells", "1,1;2,2", "--repeats", "1",
                     "--max-pulses", "40"]) == 130
    capsys.readouterr()
    run, stop, _docs, pulses = _the_run(emu, "characterize")
    assert run.status == "interrupted" and stop["exit_status"] == "abort"
    # the second cell never got a pulse: its first read saw the stop; every pulse of the
    # first is recorded once, with its read after
    n = stop["num_events"]["pulses"]
    assert stop["num_events"]["cells"] == 1 and n > 0
    assert pulses == (n, n) and run.pulses == n


def test_a_stop_ends_retention_between_two_reads(chip_home, capsys, stop_after):
    emu = chip_home
    assert cli.main(["program-weights", str(emu / "w.npy"), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    stop_after("progress", 1)
    assert cli.main(["retention", "--port", "emu", "--reads", "5000", "--path", "cell"]) == 130
    capsys.readouterr()
    run, stop, _docs, _p = _the_run(emu, "retention")
    assert run.status == "interrupted" and stop["exit_status"] == "abort"
    assert "cells" not in stop["num_events"]          # no drift verdict from a cut series


def test_a_plan_stopped_from_watch_writes_what_it_applied(emu, capsys, stop_after):
    # found by a fresh-user pass: exit 130 and no -o / --csv at all
    import csv
    import json

    from snan_hil.calibration.plans import INTERRUPTED
    rep, table = emu / "rep.json", emu / "rep.csv"
    stop_after("pulses", 5)
    assert cli.main(["plan", "run", "set", "--cells", "1,1", "2,2", "--port", "emu", "-o",
                     str(rep), "--csv", str(table)]) == 130
    err = capsys.readouterr().err
    assert "stop requested" in err and f"wrote -o {rep}" in err
    run, stop, _docs, pulses = _the_run(emu, "plan")
    assert run.status == "interrupted" and stop["exit_status"] == "abort"
    data = json.loads(rep.read_text())
    assert data["status"] == "interrupted" and data["run"]["exit_status"] == "abort"
    [cell] = data["cells"]                   # the second cell was never reached
    assert (cell["row"], cell["col"]) == (1, 1) and cell["stopped"] == INTERRUPTED
    # every pulse applied is in the report, the CSV and the history, once
    n = stop["num_events"]["pulses"]
    assert cell["pulses"] == n == pulses[0] == run.pulses and n >= 5
    with open(table, newline="") as fh:
        assert len(list(csv.DictReader(fh))) == n


def test_a_pause_from_watch_is_said_on_the_jobs_terminal(emu, capsys, monkeypatch):
    # issue 38 item 13: a job paused from watch printed nothing, so its terminal looked hung
    import functools

    from snan_hil.records.control import RunControl
    from snan_hil.tools.commands import _run
    monkeypatch.setattr(_run, "RunControl", functools.partial(RunControl, poll_s=0.0))
    original = H.Recorder.__call__
    asked = []

    def spy(self, name, doc):
        original(self, name, doc)
        if name == "event" and not asked and self.active:
            asked.append(1)                       # pause, and (as a user would) resume
            self.db.request_control(self.uid, "pause", "test")
            self.db.request_control(self.uid, "resume", "test")
    monkeypatch.setattr(H.Recorder, "__call__", spy)
    assert cli.main(["plan", "run", "set", "--cells", "1,1", "2,2", "--port", "emu",
                     "--json"]) == 0
    err = capsys.readouterr().err.splitlines()
    paused = [k for k, line in enumerate(err) if line.startswith("paused from snan-hil watch")]
    resumed = [k for k, line in enumerate(err) if line == "resumed from snan-hil watch"]
    assert len(paused) == 1 and len(resumed) == 1 and paused[0] < resumed[0], err
