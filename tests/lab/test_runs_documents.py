"""Runs as document streams (records/documents.py), the history in WAL mode with its v1 -> v2
migration, online backup, the documents export validated with Bluesky's event-model schemas,
read-cell, the raw console on both protocols, and the control channel (pause / stop between
pulses); the run's metadata options take plain text only."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import time

import pytest
from event_model import DocumentNames, schema_validators

from snan_hil.calibration.control import ControlledClient
from snan_hil.calibration.observer import CellEvent, PulseEvent
from snan_hil.common.polarity import Polarity
from snan_hil.records import history as H
from snan_hil.records.control import RunControl, StopRequested
from snan_hil.records.documents import DocumentCollector, RunMetadata, RunPublisher
from snan_hil.tools import cli

PY = [sys.executable, "-m", "snan_hil.tools.cli"]


def _validate(name: str, doc: dict) -> None:
    schema_validators[DocumentNames[name]].validate(doc)


# ------------------------------------------------------------------ the publisher
def test_publisher_documents_validate_and_carry_the_metadata():
    t = iter(range(100, 200))
    pub = RunPublisher(RunMetadata("chip 7", "ana", "first try", ("iv", "warm")),
                       kind="plan", command="snan-hil plan run x", clock=lambda: float(next(t)),
                       board_id="EMU-1", config={"a.b": 1}, seed=None)
    col = DocumentCollector()
    pub.subscribe(col)
    pub.on_pulses([PulseEvent(1, 2, Polarity.SET, 0.8, 100, None, 1.5e-4, "x")])
    pub.on_cell(CellEvent(1, 2, "done", 1.5e-4, pulses=1, detail={"k": float("nan")}))
    late = DocumentCollector()
    pub.subscribe(late)                       # a late subscriber gets start and descriptors
    pub.stop("interrupted", reason="stop requested")
    names = [n for n, _d in col.docs]
    assert names == ["start", "descriptor", "event", "descriptor", "event", "stop"]
    for name, doc in col.docs:
        _validate(name, doc)
    s = col.start
    assert (s["sample"], s["operator"], s["note"], s["tags"]) == \
        ("chip 7", "ana", "first try", ["iv", "warm"])
    assert "seed" not in s and s["config"] == {"a_b": 1}      # the schema's key pattern
    keys = col.descriptors["pulses"]["data_keys"]
    assert keys["amplitude_v"] == {"dtype": "number", "shape": [], "source": "snan-hil",
                                   "units": "V"}
    assert col.events["pulses"][0]["g_before_s"] is None and col.events["pulses"][0]["n"] == 1
    assert json.loads(col.events["cells"][0]["detail"]) == {"k": None}
    assert col.stop["exit_status"] == "abort" and col.stop["num_events"] == \
        {"pulses": 1, "cells": 1}
    assert [n for n, _d in late.docs] == ["start", "descriptor", "descriptor", "stop"]


def test_a_failing_subscriber_is_dropped_and_the_run_goes_on():
    pub = RunPublisher(kind="map")
    seen = []

    def broken(name, doc):
        raise RuntimeError("disk gone")
    pub.subscribe(broken)
    pub.subscribe(lambda n, d: seen.append(n))
    pub.on_cell(CellEvent(0, 0, "read", 1e-4))
    pub.stop()
    assert seen == ["start", "descriptor", "event", "stop"] and pub.subscribers[0] is not broken


# ------------------------------------------------------------------ WAL, migration, backup
def test_a_reader_is_not_blocked_by_a_writer(tmp_path):
    path = tmp_path / "h.sqlite"
    rec = H.Recorder(path, "pulse", command="x")
    rec.on_cell(CellEvent(1, 1, "ok", 1e-4))
    writer = sqlite3.connect(path, isolation_level=None)
    assert writer.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    writer.execute("BEGIN EXCLUSIVE")         # the strongest lock a writer can hold
    writer.execute("INSERT INTO meta(key, value) VALUES ('x', 'uncommitted')")
    t0 = time.monotonic()
    with H.History.open(path, create=False, timeout_s=0) as db:
        runs = db.runs()
        docs = db.documents(runs[0].id)
    assert time.monotonic() - t0 < 1.0
    assert len(runs) == 1 and [n for _i, n, _d in docs] == ["start", "descriptor", "event"]
    # the same read in rollback-journal mode is refused at once: the test can fail
    writer.execute("ROLLBACK")
    rec.finish("complete")
    writer.execute("PRAGMA journal_mode = DELETE")
    writer.execute("BEGIN EXCLUSIVE")
    writer.execute("INSERT INTO meta(key, value) VALUES ('x', 'uncommitted')")
    plain = sqlite3.connect(path, timeout=0)
    with pytest.raises(sqlite3.OperationalError, match="locked"):
        plain.execute("SELECT count(*) FROM runs").fetchone()
    plain.close()
    writer.execute("ROLLBACK")
    writer.close()


def test_version_1_file_is_migrated_additively(tmp_path):
    path = tmp_path / "old.sqlite"
    conn = sqlite3.connect(path, isolation_level=None)
    for stmt in H._SCHEMA.strip().split(";"):
        if stmt.strip():
            conn.execute(stmt)
    conn.execute(f"PRAGMA application_id = {H.APPLICATION_ID}")
    conn.execute("PRAGMA user_version = 1")
    conn.execute("INSERT INTO meta VALUES ('format', 'snan-hil-history/1')")
    conn.execute("INSERT INTO runs(kind, command, started_utc, status, version, record_level) "
                 "VALUES ('map', 'snan-hil map', '2026-01-01', 'complete', 'v', 'cells')")
    conn.close()
    with H.History.open(path, create=False) as db:
        assert db.schema_version == H.SCHEMA_VERSION == 4     # v1 -> ... -> v4 (run process)
        [old] = db.runs()
        assert old.kind == "map" and old.uid is None and old.tags == ()
        assert db.documents(old.id) == []
    rec = H.Recorder(path, "map", command="y", metadata=RunMetadata(sample="s"))
    rec.finish("complete")
    with H.History.open(path, create=False) as db:
        new = db.runs()[0]
        assert new.sample == "s" and db.run(new.uid[:8]).id == new.id


def test_backup_copies_while_a_run_is_open_and_never_clobbers(emu, capsys):
    path = emu / "chip.history.sqlite"
    rec = H.Recorder(path, "plan", command="x")
    rec.on_pulses([PulseEvent(0, 0, Polarity.SET, 0.8, 100, 1e-4, 2e-4)])
    rec.on_cell(CellEvent(0, 0, "ok", 2e-4))              # committed; the run still open
    dest = emu / "copy.sqlite"
    assert cli.main(["history", "backup", "-o", str(dest), "--port", "emu"]) == 0
    with H.History.open(dest, create=False) as db:
        [run] = db.runs()
        assert run.status == "running" and run.pulses == 1
    rec.finish("complete")
    assert cli.main(["history", "backup", "-o", str(dest), "--port", "emu"]) == 0   # ours
    notes = emu / "notes.txt"
    notes.write_text("keep me")
    capsys.readouterr()
    assert cli.main(["history", "backup", "-o", str(notes), "--port", "emu"]) == 2
    assert notes.read_text() == "keep me" and "--force" in capsys.readouterr().err
    assert cli.main(["history", "backup", "--port", "emu"]) == 2


# ------------------------------------------------------------------ commands and export
def test_export_documents_validate_for_every_command(emu, capsys, tmp_path):
    assert cli.main(["map", "--port", "emu", "--json", "--operator", "bo"]) == 0
    assert cli.main(["plan", "run", "potentiation-depression", "--cells", "2,2", "--port",
                     "emu", "--json"]) == 0
    assert cli.main(["read-cell", "--cell", "2,2", "--reads", "3", "--port", "emu",
                     "--json"]) == 0
    capsys.readouterr()
    out = tmp_path / "docs.jsonl"
    assert cli.main(["history", "--export", "documents", "-o", str(out), "--port", "emu"]) == 0
    docs = [json.loads(line) for line in out.read_text().splitlines()]
    for name, doc in docs:
        _validate(name, doc)
    starts = [d for n, d in docs if n == "start"]
    stops = [d for n, d in docs if n == "stop"]
    assert [s["plan_name"] for s in starts] == ["map", "plan", "read"]
    assert starts[0]["operator"] == "bo"
    assert all(s["exit_status"] == "success" for s in stops)
    plan_stop = stops[1]
    with H.History.open(emu / "chip.history.sqlite", create=False) as db:
        plan_run = db.runs(kind="plan")[0]
        assert plan_stop["num_events"]["pulses"] == plan_run.pulses == 200
        assert plan_run.uid == starts[1]["uid"]
    # the export is known as its own kind: written again over itself (its
    # signature was '["start", {' while the export writes '["start",{': refused as foreign)
    capsys.readouterr()
    assert cli.main(["history", "--export", "documents", "-o", str(out), "--port",
                     "emu"]) == 0, capsys.readouterr().err


def test_read_cell_and_bad_input(emu, capsys):
    assert cli.main(["read-cell", "--cell", "4,3", "--reads", "4", "--port", "emu",
                     "--json", "--tag", "probe"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["samples"]) == 4 and data["run"]["tags"] == ["probe"]
    assert all(0 < s["g_s"] < 2e-3 and s["adc"] > 0 for s in data["samples"])
    assert cli.main(["read-cell", "--cell", "40,3", "--port", "emu"]) == 2
    assert cli.main(["read-cell", "--cell", "4,3", "--read-code", "999", "--port", "emu"]) == 2
    assert "read limit" in capsys.readouterr().err


@pytest.mark.parametrize("protocol", ["framed", "legacy"])
def test_console_decodes_refuses_and_records(emu, protocol):
    lines = "\n".join(["read 3,5", "pulse set 3,5 0.8", "pulse set 3,5 1.6", "9,246,1,5,3",
                       "7,1147,0,100,0,2,5,3", "7,1146,0,100,0,2,5,3", "7,500,0,100,5,2,5,3",
                       "column 2 100",
                       "bogus", "quit", "read 1,1"]) + "\n"
    proc = subprocess.run([*PY, "console", "--port", "emu", "--protocol", protocol, "--json"],
                          input=lines, capture_output=True, text=True, timeout=60,
                          env=_env(emu))
    out = [json.loads(x) for x in proc.stdout.splitlines()]
    ok = [r["ok"] for r in out]
    assert len(out) == 9                                       # "quit" ends it
    # a script from a pipe: refused lines make the exit code 1, and one line says how many
    assert proc.returncode == 1 and proc.stderr.strip() == \
        f"snan-hil console: {ok.count(False)} of 9 commands refused or failed", proc.stderr
    assert ok[:2] == [True, True] and ok[2] is False
    # a typed read code above the read limit is refused, not clamped (fresh-user pass)
    assert ok[3] is False and "outside 1..245" in out[3]["reply"]
    assert "above the host's write limit" in out[2]["reply"]
    assert "largest code at or below it is 1146" in out[4]["reply"] and not ok[4]
    assert ok[5] is True and out[5]["reply"].startswith("RESET 1.3993 V")
    # SIGN 5: the firmware would take it as SET; the console sends only 0 or 1
    assert ok[6] is False and "SIGN 5: give 1 (SET) or 0 (RESET)" in out[6]["reply"]
    assert ok[7] is (protocol == "framed") and ok[8] is False
    with H.History.open(emu / "chip.history.sqlite", create=False) as db:
        [run] = db.runs(kind="console")
        assert run.pulses == 2 and run.status == "complete"
        docs = db.documents(run.id)
        console_events = [d for _i, n, d in docs if n == "event" and "command" in d["data"]]
        assert [e["data"]["command"] for e in console_events][:2] == ["read 3,5",
                                                                    "pulse set 3,5 0.8"]
        assert len(console_events) == 9


def _env(folder):
    import os
    return dict(os.environ, SNAN_HIL_EMU_STATE=str(folder / "chip.npz"),
                XDG_DATA_HOME=str(folder / "data"), SNAN_HIL_PORT="")


# ------------------------------------------------------------------ control channel
def test_run_control_pauses_resumes_and_stops(tmp_path):
    path = tmp_path / "h.sqlite"
    rec = H.Recorder(path, "plan", command="x")
    actions = []
    with H.History.open(path, create=False) as other:
        other.request_control(rec.uid, "pause", "test")
        waits = []

        def sleep(s):                           # the watcher's side, between two looks
            waits.append(s)
            if len(waits) == 3:
                other.request_control(rec.uid, "resume")
        ctl = RunControl(path, rec.uid, db=rec.db, poll_s=0.0, on_action=actions.append,
                         sleep=sleep)
        ctl.check()                               # blocks while paused, returns on resume
        assert actions == ["pause", "resume"] and len(waits) == 3
        calls = []

        class Client:
            def write_pulse(self, *a):
                calls.append(a)
                return 1

        client = ControlledClient(Client(), ctl.check)
        assert client.write_pulse(0, 0) == 1
        other.request_control(rec.uid, "stop")
        with pytest.raises(StopRequested):
            client.write_pulse(0, 1)
        assert calls == [(0, 0)]                 # the stopped pulse was never sent
    ctl.close()
    rec.finish("interrupted")


def test_stop_from_the_history_ends_a_plan_between_pulses(emu):
    plan = emu / "slow.yaml"
    plan.write_text("format: snan-hil-plan/1\nname: slow\nsteps:\n  - {action: set, "
                    "amplitude_v: 0.35, count: 400, interval_ms: 20}\n")
    proc = subprocess.Popen([*PY, "plan", "run", str(plan), "--cells", "1,1", "--port",
                             "emu"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env(emu))
    path = emu / "chip.history.sqlite"
    deadline = time.monotonic() + 60
    uid = None
    while time.monotonic() < deadline and proc.poll() is None:
        if path.exists():
            try:
                with H.History.open(path, create=False) as db:
                    runs = db.runs(kind="plan")
                    if runs and runs[0].pulses >= 5:
                        uid = runs[0].uid
                        db.request_control(uid, "stop", "test")
                        break
            except (sqlite3.Error, H.HistoryError) as exc:
                print("retry", exc)
        time.sleep(0.05)
    assert uid is not None, "the plan never recorded 5 pulses"
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "stop requested" in err, err
    with H.History.open(path, create=False) as db:
        [run] = db.runs(kind="plan")
        assert run.status == "interrupted" and 5 <= run.pulses < 400
        docs = db.documents(run.id)
        stop = [d for _i, n, d in docs if n == "stop"][0]
        pulse_rows = db.conn.execute("SELECT count(*), count(g_after_s) FROM pulses "
                                     "WHERE run_id = ?", (run.id,)).fetchone()
    assert stop["exit_status"] == "abort" and "stop requested" in stop["reason"]
    # every pulse sent is recorded whole (its read after), once
    assert pulse_rows == (run.pulses, run.pulses) == (stop["num_events"]["pulses"],) * 2
    assert any(d.get("data", {}).get("action") == "stop" for _i, n, d in docs if n == "event")


def test_software_commands_are_runs_with_metadata_and_bad_input_leaves_none(emu, capsys):
    db_path = emu / "data" / "snan-hil" / "runs.history.sqlite"
    assert cli.main(["sim", "--grid", "3", "--trials", "2", "--plot", "x.svg"]) == 2
    assert not db_path.exists()                       # refused before any work: no record
    assert cli.main(["sim", "--grid", "3", "--trials", "3", "--json", "--operator", "kim",
                     "--tag", "sw"]) == 0
    with H.History.open(db_path, create=False) as db:
        [run] = db.runs(kind="experiment")
        assert (run.operator, run.tags, run.status) == ("kim", ("sw",), "complete")
        docs = db.documents(run.id)
    for name, doc in [(n, d) for _i, n, d in docs]:
        _validate(name, doc)
    assert [n for _i, n, _d in docs][0] == "start" and docs[-1][1] == "stop"
    assert any(d.get("data", {}).get("task") for _i, n, d in docs if n == "event")


@pytest.mark.parametrize("option, value, needle", [
    ("--note", "a\x1b[31mred", "argument --note: holds the control character '\\x1b'"),
    ("--operator", "ana\tbo", "argument --operator: holds the control character '\\t'"),
    ("--sample", "   ", "argument --sample: a blank value"),
    ("--tag", "", "argument --tag: a blank tag; give a word"),
    ("--tag", "x\ny", "argument --tag: 'x\\ny' holds the control character"),
])
def test_run_metadata_is_plain_text(emu, one_line, option, value, needle):
    # found by a fresh-user pass: an escape sequence was recorded and printed raw by
    # `history`, blank values were accepted, --tag "" was refused as "without commas"
    with pytest.raises(SystemExit) as exc:           # argparse's own error, one line
        cli.main(["plan", "run", "set", "--cells", "1,1", "--port", "emu", option, value])
    assert exc.value.code == 2 and needle in one_line()
    assert not list(emu.rglob("*.sqlite")) and not (emu / "chip.npz").exists()
