"""``snan-hil selftest``: the table, the JSON report with provenance, the chip's history, exit
codes."""

from __future__ import annotations

import json
import sqlite3

from snan_hil.tools import cli


def test_selftest_writes_report_records_history_and_exits_by_verdict(tmp_path, capsys):
    chip = tmp_path / "chip.npz"
    report = tmp_path / "r.json"
    code = cli.main(["selftest", "--port", f"emu://?state={chip}", "--report", str(report),
                     "--allow-pulses", "3,5"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "board self-test" in out and "PASSED" in out
    data = json.loads(report.read_text())
    assert data["format"] == "snan-hil-selftest/1" and data["summary"]["passed"]
    assert data["session"]["identity"]["board_id"].startswith("EMU-")
    assert {i["item"] for i in data["items"]} >= {"link", "cell_reads", "conformance"}
    db = sqlite3.connect(tmp_path / "chip.history.sqlite")
    kinds = [k for (k,) in db.execute("select kind from runs")]
    assert kinds == ["selftest"]
    assert db.execute("select count(*) from pulses").fetchone()[0] == 2      # SET and RESET
    assert db.execute("select count(*) from cell_results").fetchone()[0] >= 256

    code = cli.main(["selftest", "--port", f"emu://?state={chip}&fault=gain:0.8", "--report",
                     str(report), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 1 and "gain" in summary["failed_items"]


def test_bad_cells_or_items_are_one_line_exit_2(tmp_path, capsys):
    chip = tmp_path / "chip.npz"
    assert cli.main(["selftest", "--port", f"emu://?state={chip}", "--allow-pulses",
                     "40,1"]) == 2
    assert "--allow-pulses" in capsys.readouterr().err
    assert cli.main(["selftest", "--port", f"emu://?state={chip}", "--only", "bogus"]) == 2
    assert "unknown self-test item" in capsys.readouterr().err


def test_with_a_layout_the_column_multiply_is_checked_against_numpy(tmp_path, capsys):
    port = f"emu://?state={tmp_path}/chip.npz"
    assert cli.main(["mac", "--port", port, "--weights", "random", "--grid", "3",
                     "--vectors", "2", "--out", str(tmp_path / "m"), "--json"]) == 0
    capsys.readouterr()
    report = tmp_path / "r.json"
    assert cli.main(["selftest", "--port", port, "--only", "cell_reads,mac", "--report",
                     str(report), "--json"]) == 0
    data = json.loads(report.read_text())
    mac = next(i for i in data["items"] if i["item"] == "mac")
    assert mac["status"] == "pass" and mac["data"]["summary"]["samples"] > 0
