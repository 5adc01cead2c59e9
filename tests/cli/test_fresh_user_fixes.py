"""Bad input found by a fresh-user pass: each one line, exit 2, before any work."""

import pytest

from snan_hil.tools import cli


@pytest.mark.parametrize("argv, needle", [
    (["learn", "--port", "emu", "--arms", "software,software", "--out", "L"],
     "names an arm twice"),
    (["history", "--port", "emu", "--export", "runs", "--kind", "learn"],
     "--kind filters the list of runs"),
    (["plan", "run", "parking", "--cells", "3,5", "--baud", "-5", "--dry-run"],
     "--baud must be positive"),
    (["learn", "--port", "emu", "--arms", "device", "--model", "notes.txt", "--out", "L"],
     "not JSON"),
    # a seed past SQLite's INTEGER pulsed the chip, then failed to be recorded (traceback)
    (["learn", "--port", "emu", "--arms", "chip", "--seed", str(2**70), "--out", "L"],
     "at most 9223372036854775807"),
    (["demo", "--software-only", "--seed", str(2**64), "--out", "L"],
     "at most 9223372036854775807"),
    # without a terminal (pytest's stdin is none) watch said nothing useful, then hung
    (["watch", "--port", "emu", "--run", "1"], "give --screenshot FILE.svg"),
])
def test_one_line_exit_2(emu, one_line, monkeypatch, argv, needle):
    monkeypatch.chdir(emu)
    (emu / "notes.txt").write_text("hello\n")
    assert cli.main(argv) == 2
    assert needle in one_line()
    assert not (emu / "L").exists()


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


def test_a_plan_past_the_boards_own_limit_is_refused_before_its_first_pulse(emu, one_line):
    # found by a fresh-user pass: --max-write-v 1.6 let step 1 run, the board refused step 2;
    # now --max-write-v cannot raise the board's limit (issue 32): refused before the plan
    plan = emu / "hot.yaml"
    plan.write_text("format: snan-hil-plan/1\nname: hot\nsteps:\n"
                    "  - {action: set, amplitude_v: 0.8}\n  - {action: set, amplitude_v: 1.5}\n")
    assert cli.main(["plan", "run", str(plan), "--cells", "1,1", "--max-write-v", "1.6",
                     "--port", "emu"]) == 2
    assert "--max-write-v 1.6: above the board's declared write limit 1.4 V" in one_line()
    from snan_hil.records import history as H
    for db_path in emu.rglob("*.sqlite"):
        with H.History.open(db_path, create=False) as db:
            assert not db.runs(kind="plan")                        # nothing ran, nothing sent


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


def test_the_plan_limit_example_of_bench_md_is_the_real_line(emu, one_line, monkeypatch):
    # found by a fresh-user pass: the doc's line named the plan file, the real one does not
    import re
    from pathlib import Path
    doc = " ".join((Path(__file__).parents[2] / "docs" / "bench.md").read_text().split())
    [quoted] = re.findall(r"`(snan-hil plan: error: plan t: step 2 .*?nothing was sent)`", doc)
    monkeypatch.chdir(emu)
    (emu / "hot.yaml").write_text("format: snan-hil-plan/1\nname: t\nsteps:\n"
                                  "  - {action: set, amplitude_v: 0.8}\n"
                                  "  - {action: set, amplitude_v: 1.5}\n")
    assert cli.main(["plan", "run", "hot.yaml", "--cells", "3,5", "--port", "emu"]) == 2
    assert one_line() == quoted
