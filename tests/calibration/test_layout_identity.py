"""Layouts belong to the chip (board identity from INFO), not to the port string; conductance
targets are checked against the board before any pulse; a full spare table says how to clear
it; a file that is not a layout, or another board's layout given to learn, is one line before
anything is written."""

import json
import os
import signal
import sys

import numpy as np
import pytest

from snan_hil.calibration.layout import Layout
from snan_hil.crossbar_model import CrossbarArray
from snan_hil.firmware_emu.journal import count_records, journal_path
from snan_hil.tools import cli

PY = [sys.executable, "-m", "snan_hil.tools.cli"]


@pytest.fixture
def env(chip_home):
    return chip_home


def test_targets_beyond_the_board_are_refused_before_any_pulse(env, capsys, one_line):
    capsys.readouterr()
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu",
                     "--g-max-us", "1e9"]) == 2
    err = one_line()
    assert "1e+09" in err and "1400" in err and "--g-max-us" in err
    assert not (env / "chip.layout.json").exists()
    # nothing was pulsed: the chip is the fresh one, its journal holds no cell change
    chip = CrossbarArray.load(str(env / "chip.npz"))
    assert np.array_equal(chip.state, CrossbarArray.from_yaml(None, seed=0).state)
    assert count_records(journal_path(env / "chip.npz")) == 0
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu",
                     "--g-min-us", "5"]) == 2
    assert "15" in one_line()


def test_a_full_spare_table_names_the_commands_that_clear_it(env, capsys, one_line):
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu", "--json"]) == 0
    path = env / "chip.layout.json"
    layout = Layout.load(path)
    for r in range(layout.block_rows, 32):           # every spare, and a block cell, bad
        for c in range(8):
            layout.mark_bad(r, c, "test: marked by an earlier run")
    layout.mark_bad(0, 0, "test: marked by an earlier run")
    layout.save(path)
    capsys.readouterr()
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu"]) == 2
    err = one_line()
    assert "no free spare cell" in err and "--fresh-layout" in err and "--reset-chip" in err
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu",
                     "--fresh-layout", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["summary"]["ok"] == 24


def stop(proc):
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=30)


def test_a_served_chip_keeps_its_layout_across_restarts_and_ports(env, capsys, start_emu_server,
                                                                 one_line):
    child_env = dict(os.environ)                    # the fixture's SNAN_HIL_EMU_STATE, XDG
    server, url = start_emu_server(env / "served.npz", env=child_env)
    try:
        assert cli.main(["program-weights", str(env / "w.npy"), "--port", url, "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
    finally:
        stop(server)
    # served on this machine, the chip keeps its files beside its state file, as in-process
    assert out["layout"] == str(env / "served.layout.json")
    assert out["report"] == str(env / "served.program-report.json")
    assert (env / "served.history.sqlite").is_file()
    layouts = env / "xdg" / "snan-hil" / "layouts"
    assert not list(layouts.glob("*"))                            # nothing keyed by board id
    assert url.replace(":", "_") not in " ".join(p.name for p in env.rglob("*"))
    serial = Layout.load(out["layout"]).board["board_id"].partition("/")[2]
    capsys.readouterr()
    assert cli.main(["history", "--port", url, "--board", f"EMU-4D430001/{serial}",
                     "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["history"] == str(env / "served.history.sqlite")
    assert [r["kind"] for r in data["runs"]] == ["program"]
    assert cli.main(["history", "--port", url]) == 2            # the port alone names no board
    assert "--board" in one_line()
    # restarted on the same chip, on another port: the same layout
    server, url2 = start_emu_server(env / "served.npz", env=child_env)
    try:
        assert cli.main(["read-weights", "--port", url2, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["errors"]["max_abs"] < 0.06
    finally:
        stop(server)
    # another chip: no layout of its own, and the first chip's is refused
    server, url3 = start_emu_server(env / "other.npz", env=child_env)
    try:
        capsys.readouterr()
        assert cli.main(["read-weights", "--port", url3]) == 2
        assert "program-weights" in one_line()
        assert cli.main(["read-weights", "--port", url3, "--layout", out["layout"]]) == 2
        err = one_line()
        assert serial in err and "another chip" in err
    finally:
        stop(server)
    # resetting the chip forgets its layout (its history database, a record, stays)
    assert cli.main(["emu", "--reset-chip", "--state", str(env / "served.npz")]) == 0
    assert sorted(p.name for p in env.glob("served.*")) == [
        f"served.history-{serial}.sqlite", "served.npz"]


def test_reset_chip_of_port_emu_forgets_its_layout_and_sets_its_history_aside(env, capsys):
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu", "--json"]) == 0
    serial = Layout.load(env / "chip.layout.json").board["board_id"].partition("/")[2]
    assert (env / "chip.history.sqlite").is_file()          # beside the chip, like its layout
    assert cli.main(["emu", "--reset-chip"]) == 0
    assert not (env / "chip.layout.json").exists()
    assert not (env / "chip.history.sqlite").exists()       # the new chip starts its own
    kept = env / f"chip.history-{serial}.sqlite"
    capsys.readouterr()
    assert cli.main(["history", "--history", str(kept), "--json"]) == 0
    assert [r["kind"] for r in json.loads(capsys.readouterr().out)["runs"]] == ["program"]


def test_reset_chip_takes_the_old_chips_pending_records_with_its_history(env, capsys,
                                                                         monkeypatch):
    # records a lock kept out of the old chip's history must not go into the new chip's
    import sqlite3

    from snan_hil.records import history as H
    from snan_hil.records.pending import pending_files
    assert cli.main(["map", "--port", "emu", "--json"]) == 0
    db = env / "chip.history.sqlite"
    monkeypatch.setattr(H, "FINISH_WAIT_S", 0.1)
    hog = sqlite3.connect(db, isolation_level=None)
    hog.execute("BEGIN EXCLUSIVE")
    try:
        assert cli.main(["read-cell", "--cell", "1,1", "--port", "emu", "--json"]) == 0
    finally:
        hog.execute("ROLLBACK")
        hog.close()
    assert len(pending_files(db)) == 1
    assert cli.main(["emu", "--reset-chip"]) == 0
    capsys.readouterr()
    [kept] = env.glob("chip.history-*.sqlite")
    assert pending_files(db) == [] and len(pending_files(kept)) == 1
    assert cli.main(["history", "--history", str(kept), "--json"]) == 0
    assert sorted(r["kind"] for r in json.loads(capsys.readouterr().out)["runs"]) == \
        ["map", "read"]


@pytest.mark.parametrize("text", ["[1, 2]", '"layout"', "null"])
def test_a_layout_file_that_is_not_a_json_object_is_one_line(tmp_path, text):
    from snan_hil.calibration.layout import LayoutError
    path = tmp_path / "chip.layout.json"
    path.write_text(text)
    with pytest.raises(LayoutError, match="is not a layout") as err:
        Layout.load(path)
    assert "\n" not in str(err.value) and path.read_text() == text    # the file is untouched


def _foreign_layout(emu, capsys):
    """A layout programmed on another emulated chip."""
    from snan_hil.calibration.testing import grid_weights
    np.save(emu / "w.npy", grid_weights(3, 3, seed=2))
    layout = emu / "other.layout.json"
    assert cli.main(["program-weights", str(emu / "w.npy"), "--port",
                     f"emu://?state={emu / 'other.npz'}", "--layout", str(layout),
                     "--json"]) == 0
    capsys.readouterr()
    return layout


def test_learn_refuses_another_boards_layout_before_opening_its_folder(emu, capsys, one_line):
    layout = _foreign_layout(emu, capsys)
    model = emu / "model.json"
    assert cli.main(["characterize", "--port", "emu", "--cells", "0,0", "--repeats", "1",
                     "--json", "--model", str(model)]) == 0
    capsys.readouterr()
    out = emu / "learn"
    argv = ["learn", "--port", "emu", "--arms", "chip", "--sessions", "1", "--cycles", "1",
            "--model", str(model), "--out", str(out), "--no-figure"]
    assert cli.main([*argv, "--layout", str(layout)]) == 2
    line = one_line()
    assert "was made on board" in line and str(layout) in line
    assert not out.exists()                 # the corrected command starts afresh
