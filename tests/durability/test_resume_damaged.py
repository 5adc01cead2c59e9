"""A damaged checkpoint never reaches the live chip or layout (issue 13 follow-up): ``--resume``
checks the snapshots it would put back before it changes anything, names the damaged file in
one line and exits 2; the emulated chip (state file and journal) and its layout stay as they
were."""

import json
import shutil
from pathlib import Path

import pytest

from snan_hil.tools import cli

SHORT = ["--set", "grid.max_steps=15"]


@pytest.fixture(scope="module")
def stopped_run(tmp_path_factory, cli_trained):
    """A compare whose checkpoint looks like one stopped while set 1 was programmed: set 0
    finished, the chip and layout the job runner saved before set 1 (its boundary
    ``boundaries/before-set-1``: here the finished run's chip and layout), set 1 and the
    spike measurement not committed."""
    d = tmp_path_factory.mktemp("stopped")
    mp = pytest.MonkeyPatch()
    mp.setenv("SNAN_HIL_EMU_STATE", str(d / "chip.npz"))
    mp.setenv("XDG_DATA_HOME", str(d / "xdg"))
    shutil.copy(cli_trained, d / "w.npz")      # the session's trained weights (conftest)
    try:
        assert cli.main(compare_argv(d)) == 0
    finally:
        mp.undo()
    cp = d / "out" / "checkpoint"
    for name in ("unit-set-1.json", "unit-geometry.json"):
        (cp / name).unlink()
    boundary = cp / "boundaries" / "before-set-1"
    boundary.mkdir(parents=True)
    shutil.copy(d / "chip.npz", boundary / "chip")
    shutil.copy(d / "chip.layout.json", boundary / "layout.json")
    (boundary / "saved").write_text("chip and layout saved before the unit\n")
    record = json.loads((cp / "run.json").read_text())
    record["status"] = "running"
    (cp / "run.json").write_text(json.dumps(record))
    (d / "out" / "compare.json").unlink()
    return d


def compare_argv(d, *extra):
    return ["compare", "--weights", str(d / "w.npz"), "--port", "emu", "--out", str(d / "out"),
            "--launches", "2", "--seed", "4", "--json", "--no-figure", *SHORT, *extra]


def live_files(d):
    return {p.name: p.read_bytes() for p in (d / "chip.npz", d / "chip.npz.journal",
                                             d / "chip.layout.json") if p.exists()}


@pytest.mark.parametrize("damage", ["chip", "layout", "layout-format"])
def test_resume_refuses_a_damaged_checkpoint_and_leaves_the_live_chip_alone(
        stopped_run, tmp_path, monkeypatch, capsys, damage):
    d = tmp_path / "run"
    shutil.copytree(stopped_run, d)
    cp = d / "out" / "checkpoint"
    run_json = cp / "run.json"                  # the copy's paths, as if it had run there
    run_json.write_text(run_json.read_text().replace(str(stopped_run), str(d)))
    if damage == "chip":
        victim = cp / "boundaries" / "before-set-1" / "chip"
        data = bytearray(victim.read_bytes())
        data[2000:2100] = bytes(b ^ 0xFF for b in data[2000:2100])
        victim.write_bytes(bytes(data))
    elif damage == "layout":
        victim = cp / "boundaries" / "before-set-1" / "layout.json"
        victim.write_text('{"x":1}')
    else:
        victim = cp / "boundaries" / "before-set-1" / "layout.json"
        victim.write_text(victim.read_text()[:500])
    before = live_files(d)
    assert "chip.npz" in before and "chip.layout.json" in before
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(d / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(d / "xdg"))
    capsys.readouterr()
    assert cli.main(compare_argv(d, "--resume")) == 2
    whole = capsys.readouterr().err
    err = whole.strip().splitlines()[-1]        # (an info line "resuming the run" before)
    assert str(victim) in err and "damaged" in err and "untouched" in err, whole
    assert "Traceback" not in whole and whole.count("error:") == 1
    assert live_files(d) == before              # nothing of the live chip was touched
    assert Path(victim).exists()                # the evidence stays


def test_a_truncated_unit_is_refused_before_resuming_is_said(tmp_path, monkeypatch, capsys,
                                                             cli_trained):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    argv = ["compare", "--weights", str(cli_trained), "--out", str(tmp_path / "out"),
            "--launches", "2", "--seed", "4", "--json", "--no-figure", *SHORT,
            "--scenarios", "sw_noastro,sw_astro"]
    assert cli.main(argv) == 0
    capsys.readouterr()
    cp = tmp_path / "out" / "checkpoint"
    unit = sorted(cp.glob("unit-*.json"))[-1]
    unit.write_bytes(unit.read_bytes()[:40])              # cut mid-write by a crash
    record = json.loads((cp / "run.json").read_text())
    record["status"] = "running"
    (cp / "run.json").write_text(json.dumps(record))
    assert cli.main([*argv, "--resume"]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert "\n" not in err and str(unit) in err and "unreadable" in err, err
    assert "resuming" not in err and cap.out == ""
