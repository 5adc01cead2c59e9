"""The chip history database (snan_hil.records.history): schema, marker, records, cell life, CSV
export, and the failure policy (not ours: refused; damaged: refused, or one warning and the job
stops before its next pulse; locked: tests/lab/test_history_contention.py); ``snan-hil
history``: --board picks that board's database, the runs table at 80 columns, exports of one
run by id or uid, a backup of a damaged database writes nothing."""

from __future__ import annotations

import csv
import io
import json
import sqlite3
import threading

import pytest

from snan_hil.records import history as H
from snan_hil.calibration.layout import Layout
from snan_hil.calibration.observer import CellEvent, PulseEvent
from snan_hil.common.polarity import Polarity
from snan_hil.records.documents import RunMetadata
from snan_hil.records.history import History
from snan_hil.tools import cli


def _record_one(path, warnings=None, level="pulses"):
    rec = H.Recorder(path, "pulse", command="snan-hil pulse --cell 1,2", level=level,
                     warn=(warnings.append if warnings is not None else None),
                     board_id="EMU-1", port="emu", protocol="framed", seed=3,
                     config={"a": 1})
    rec.on_pulses([PulseEvent(1, 2, Polarity.SET, 0.8, 100, 1e-4, 1.2e-4, "ticket"),
                   PulseEvent(1, 2, Polarity.SET, 0.9, 100, 1.2e-4, 1.5e-4, "ticket")])
    rec.on_cell(CellEvent(1, 2, "condition met", 1.5e-4, target_s=1.4e-4, pulses=2))
    rec.finish("complete", {"pulses": 2})
    return rec


def test_schema_marker_and_records(tmp_path):
    path = tmp_path / "h.sqlite"
    rec = _record_one(path)
    assert rec.failed is None and rec.recorded == {"cells": 1, "pulses": 2}
    head = path.read_bytes()[:100]
    assert head.startswith(b"SQLite format 3\x00")
    assert int.from_bytes(head[68:72], "big") == H.APPLICATION_ID
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA user_version").fetchone()[0] == H.SCHEMA_VERSION
    assert dict(conn.execute("SELECT key, value FROM meta"))["format"] == H.FORMAT
    conn.close()
    with H.History.open(path, create=False) as db:
        runs = db.runs()
        assert len(runs) == 1
        r = runs[0]
        assert (r.kind, r.status, r.board_id, r.seed, r.cells, r.pulses) == \
            ("pulse", "complete", "EMU-1", 3, 1, 2)
        assert r.config == {"a": 1} and r.summary == {"pulses": 2}
        assert r.finished_utc is not None and r.version.startswith("snan-hil ")


def test_levels_limit_what_is_written(tmp_path):
    for level, cells, pulses in (("runs", 0, 0), ("cells", 1, 0), ("pulses", 1, 2)):
        path = tmp_path / f"{level}.sqlite"
        _record_one(path, level=level)
        with H.History.open(path, create=False) as db:
            r = db.runs()[0]
            assert (r.cells, r.pulses, r.record_level) == (cells, pulses, level)


def test_cell_life_counts_pulses_over_runs(tmp_path):
    path = tmp_path / "h.sqlite"
    _record_one(path)
    _record_one(path)
    with H.History.open(path) as db:
        life = db.cell_life(1, 2)
        assert [e.event for e in life] == ["pulse", "pulse", "result"] * 2
        assert [e.pulses_total for e in life] == [1, 2, 2, 3, 4, 4]
        assert life[0].polarity == "SET" and life[0].amplitude_v == 0.8
        assert life[0].g_before_s == pytest.approx(1e-4) and life[1].g_s == pytest.approx(1.5e-4)
        assert {e.run_id for e in life} == {1, 2}
        assert db.cell_life(0, 0) == []


def test_csv_export_has_header_and_rows(tmp_path):
    path = tmp_path / "h.sqlite"
    _record_one(path)
    with H.History.open(path) as db:
        rows = list(csv.reader(io.StringIO(db.export_csv("pulses"))))
        assert tuple(rows[0]) == H.TABLE_COLUMNS["pulses"]
        assert len(rows) == 3 and rows[1][7] == "SET"
        assert len(list(csv.reader(io.StringIO(db.export_csv("runs", run_id=1))))) == 2
        assert len(list(csv.reader(io.StringIO(db.export_csv("runs", run_id=9))))) == 1
        with pytest.raises(H.HistoryError):
            db.export_csv("nope")


@pytest.mark.parametrize("content,what", [
    (b"hello, this is a text file\n", "not an SQLite database"),
    (b"SQLite format 3\x00" + b"\x00" * 20, "truncated"),
])
def test_file_that_is_not_ours_is_refused(tmp_path, content, what):
    path = tmp_path / "x.sqlite"
    path.write_bytes(content)
    with pytest.raises(H.HistoryError, match=what):
        H.check_history_file(path)
    assert path.read_bytes() == content


def test_other_programs_sqlite_is_refused_and_untouched(tmp_path):
    path = tmp_path / "other.sqlite"
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE t (x)")
    conn.commit()
    conn.close()
    before = path.read_bytes()
    with pytest.raises(H.HistoryError, match="another program"):
        H.History.open(path)
    assert path.read_bytes() == before


def test_missing_and_empty_files_are_fine(tmp_path):
    assert H.check_history_file(tmp_path / "new.sqlite") == tmp_path / "new.sqlite"
    (tmp_path / "empty.sqlite").write_bytes(b"")
    _record_one(tmp_path / "empty.sqlite")
    with pytest.raises(H.HistoryError, match="no history database"):
        H.History.open(tmp_path / "none.sqlite", create=False)


def test_damaged_database_warns_once_and_stops_the_job_before_its_next_pulse(tmp_path):
    path = tmp_path / "h.sqlite"
    _record_one(path)
    data = bytearray(path.read_bytes())
    page = 4096
    for k in range(page, len(data), 7):              # header intact, every table page broken
        data[k] = (data[k] + 0x5A) & 0xFF
    path.write_bytes(bytes(data))
    H.check_history_file(path)                         # still ours by its header
    with pytest.raises(H.HistoryError, match="damaged .*history recover"):
        H.check_history_intact(path)                   # what the opener checks first
    warnings: list[str] = []
    rec = _record_one(path, warnings)
    assert rec.failed is not None and len(warnings) == 1
    assert "damaged" in warnings[0] and "stops before its next pulse" in warnings[0]
    from snan_hil.records.control import RecordingStopped
    with pytest.raises(RecordingStopped, match="stopped before its next pulse"):
        rec.check()
    assert path.read_bytes() == bytes(data)            # nothing was added to it


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "h.sqlite"
    _record_one(path)
    conn = sqlite3.connect(path)
    conn.execute(f"PRAGMA user_version = {H.SCHEMA_VERSION + 1}")
    conn.commit()
    conn.close()
    with pytest.raises(H.HistoryError, match="schema version"):
        H.History.open(path)


def test_recorder_context_marks_interrupted_runs(tmp_path):
    path = tmp_path / "h.sqlite"
    with pytest.raises(KeyboardInterrupt):
        with H.Recorder(path, "program", command="x"):
            raise KeyboardInterrupt
    with pytest.raises(RuntimeError):
        with H.Recorder(path, "program", command="y"):
            raise RuntimeError("boom")
    with H.History.open(path) as db:
        runs = db.runs()
        assert [r.status for r in runs] == ["failed", "interrupted"]
        assert "boom" in runs[0].summary["error"]


def test_concurrent_recorders_in_threads_do_not_lose_rows(tmp_path):
    path = tmp_path / "h.sqlite"
    H.History.open(path).close()
    errors: list[str] = []

    def work():
        _record_one(path, errors)
    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    with H.History.open(path) as db:
        assert len(db.runs()) == 4 and len(db.cell_life(1, 2)) == 12


def test_a_run_whose_process_was_killed_shows_as_crashed(tmp_path):
    """kill -9 leaves a run 'running' in the file; every reader shows it 'crashed' (its pid is
    gone), a later run's start writes it so; a run whose process lives stays 'running'."""
    import os
    import subprocess
    import sys
    path = tmp_path / "h.sqlite"
    code = ("import os, sys; from snan_hil.records.history import Recorder; "
            "r = Recorder(sys.argv[1], 'pulse', command='snan-hil pulse'); "
            "print(r.run_id, flush=True); os.kill(os.getpid(), 9)")
    proc = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == -9, proc.stderr
    killed = int(proc.stdout.split()[0])
    with H.History.open(path) as db:
        assert db.conn.execute("SELECT status FROM runs WHERE id = ?",
                               (killed,)).fetchone()[0] == "running"     # as the kill left it
        assert db.run(killed).status == "crashed"                        # as readers see it
        live = db.begin_run("pulse", command="snan-hil pulse")           # this process
        assert db.run(live).status == "running" and db.run(live).pid == os.getpid()
        assert db.conn.execute("SELECT status FROM runs WHERE id = ?",
                               (killed,)).fetchone()[0] == "crashed"     # written at a start
        # a pid now used by a process started after the run is not the run's process
        db.conn.execute("UPDATE runs SET started_utc = '2000-01-01T00:00:00.000+00:00' "
                        "WHERE id = ?", (live,))
        assert db.run(live).status == "crashed"


def test_history_lists_each_runs_sample_and_operator(tmp_path, capsys, monkeypatch):
    from snan_hil.records.documents import RunMetadata
    from snan_hil.tools import cli
    monkeypatch.setenv("COLUMNS", "200")
    path = tmp_path / "h.sqlite"
    H.Recorder(path, "read", command="snan-hil read-cell",
               metadata=RunMetadata(sample="wafer7", operator="kim")).finish("complete")
    H.Recorder(path, "read", command="snan-hil read-cell").finish("complete")
    assert cli.main(["history", "--history", str(path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "sample / operator" in "\n".join(lines)
    assert any("wafer7 / kim" in line for line in lines)
    assert any(" - / - " in line for line in lines)


def test_dir_of_the_package_shows_open_board():
    import snan_hil
    assert "open_board" in dir(snan_hil) and "open_board" in snan_hil.__all__


def test_a_cells_life_figure_names_the_port_its_runs_were_on(tmp_path, monkeypatch):
    # issue 38 item 13: the title said "port emu" (the default --port) for runs on a pty
    from snan_hil.tools import bench_figures, cli
    path = tmp_path / "h.sqlite"
    rec = H.Recorder(path, "pulse", command="x", port="/dev/pts/7", board_id="MC-1")
    rec.on_pulses([PulseEvent(1, 2, Polarity.SET, 0.8, 100, 1e-4, 1.2e-4, "ticket")])
    rec.finish("complete")
    titles: list[str] = []
    monkeypatch.setattr(bench_figures, "plot_cell_life",
                        lambda life, png, title: titles.append(title))
    assert cli.main(["history", "--history", str(path), "--cell", "1,2", "--png",
                     str(tmp_path / "c.png")]) == 0
    assert "board MC-1, port /dev/pts/7," in titles[0] and "emu" not in titles[0]


def test_board_option_selects_that_boards_history(programmed_emu, one_line, capsys):
    d = programmed_emu
    board = str(Layout.load(d / "chip.layout.json").board["board_id"])
    assert board.startswith("EMU-4D430001/")
    assert cli.main(["history", "--board", board, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["history"] == str(d / "chip.history.sqlite")
    # a board without a database: one line naming the boards that have one, exit 2
    for argv in (["history", "--board", "NOPE"], ["cells", "show", "--board", "NOPE"],
                 ["history", "--board", "EMU-4D430001/000000000000"]):
        assert cli.main(argv) == 2
        assert board in one_line()
    # a real board's database in the layouts folder, by its id
    other = d / "data" / "snan-hil" / "layouts" / "MC-7_1.history.sqlite"
    other.parent.mkdir(parents=True)
    with History.open(other) as db:
        assert db.runs() == []
    assert cli.main(["history", "--board", "MC-7/1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"history": str(other), "runs": []}


def test_history_table_keeps_run_kind_status_whole_at_80_columns(programmed_emu, capsys,
                                                                 monkeypatch):
    from rich.console import Console

    from snan_hil.tools import console as console_mod
    from snan_hil.tools.commands import history as history_cmd
    narrow = Console(width=80, file=io.StringIO(), force_terminal=False)
    monkeypatch.setattr(history_cmd, "console", narrow)
    monkeypatch.setattr(console_mod, "console", narrow)
    for _ in range(3):
        assert cli.main(["pulse", "--port", "emu", "--cell", "31,7", "--polarity", "set",
                         "--amplitude", "0.5", "--json"]) == 0
    capsys.readouterr()
    assert cli.main(["history", "--port", "emu"]) == 0
    text = narrow.file.getvalue()
    rows = [line for line in text.splitlines() if line.startswith("│")]
    cells = [[c.strip() for c in line.strip("│").split("│")] for line in rows]
    firsts = [c for c in cells if c[0]]
    assert [c[0] for c in firsts] == ["4", "3", "2", "1"]          # run ids whole
    assert [c[1] for c in firsts] == ["pulse"] * 3 + ["program"]
    assert all(c[3] == "complete" for c in firsts)
    assert "…" not in "".join(c[0] + c[1] + c[3] for c in cells)


def test_history_export_of_a_missing_run_and_run_without_export(programmed_emu, one_line, capsys):
    d = programmed_emu
    assert cli.main(["history", "--port", "emu", "--export", "runs", "--run", "999", "-o",
                     str(d / "r.csv")]) == 2
    assert "--run 999: no such run" in one_line()
    assert not (d / "r.csv").exists()
    assert cli.main(["history", "--port", "emu", "--run", "1"]) == 2
    assert "give --export" in one_line()
    assert cli.main(["history", "--port", "emu", "--export", "runs", "--run", "1"]) == 0
    assert capsys.readouterr().out.count("\n") == 2              # header + run 1


def test_backup_of_a_damaged_history_writes_nothing(tmp_path, one_line):
    # found by a fresh-user pass: a traceback, and a damaged copy left under the backup's name
    import os

    from snan_hil.records import history as H
    path = tmp_path / "h.sqlite"
    for _ in range(300):
        H.Recorder(path, "plan", command="x" * 200).finish("complete", {})
    with H.History.open(path, create=False) as db:
        db.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        db.conn.execute("PRAGMA journal_mode = DELETE")
    with open(path, "r+b") as f:                       # a run of damaged pages mid-file
        f.seek(os.path.getsize(path) // 2)
        f.write(b"\xff" * 8192)
    dest = tmp_path / "copy.sqlite"
    assert cli.main(["history", "backup", "--history", str(path), "-o", str(dest)]) == 2
    assert "malformed; nothing was written to" in one_line()
    assert not dest.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["h.sqlite"]


def test_history_export_takes_a_run_by_uid_as_watch_does(emu, capsys, one_line):
    # found by a fresh-user pass: --export --run took integer ids only, where watch and
    # plan repeat take the uid 'snan-hil history' and the reports show
    import json
    uids = []
    for _ in range(2):
        assert cli.main(["read-cell", "--cell", "4,3", "--reads", "2", "--port", "emu",
                         "--json"]) == 0
        uids.append(json.loads(capsys.readouterr().out)["run"]["uid"])
    for ref in (uids[1], uids[1][:8]):
        assert cli.main(["history", "--port", "emu", "--export", "documents", "--run",
                         ref]) == 0
        docs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
        assert docs[0][0] == "start" and docs[0][1]["uid"] == uids[1]
        assert sum(name == "start" for name, _doc in docs) == 1
    assert cli.main(["history", "--port", "emu", "--export", "runs", "--run", uids[0]]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert len(rows) == 2 and uids[0] in rows[1]
    assert cli.main(["history", "--port", "emu", "--export", "runs", "--run", "nope-nope",
                     "-o", str(emu / "r.csv")]) == 2
    assert "--run nope-nope: no such run" in one_line() and not (emu / "r.csv").exists()


def test_a_uid_prefix_of_digits_names_its_run_not_an_id(tmp_path):
    """uids are hex, so 1 in about 60 eight-character prefixes is all digits: such a prefix
    naming no run id names the run whose uid it begins (plan repeat failed on one in CI)."""
    with H.History.open(tmp_path / "h.sqlite") as db:
        first = db.begin_run("pulse", command="snan-hil pulse")
        second = db.begin_run("pulse", command="snan-hil pulse",
                              metadata=RunMetadata(uid="07672105-aaaa-4aaa-8aaa-aaaaaaaaaaaa"))
        assert db.run("07672105").id == second
        assert db.run(str(first)).id == first               # digits naming an id stay an id
        assert db.run("0767") is None                        # too short to be a prefix
