"""Nothing lost on a user mistake found after a run folder was opened (the r4 fresh-user pass,
#23 "NOT fixed" 3): the refused command leaves ``--out`` as it was, so the corrected command
is not refused for a checkpoint of a run that did nothing."""

import json

import numpy as np

from snan_hil.host import checkpoint as C
from snan_hil.tools import cli


def test_a_new_runs_checkpoint_with_no_unit_is_removed_and_nothing_else(tmp_path):
    made = C.open_run(tmp_path / "new", "demo", {"seed": 1}, resume=False)
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "mine.txt").write_text("a user's file")
    kept = C.open_run(tmp_path / "old", "demo", {"seed": 1}, resume=False)
    worked = C.open_run(tmp_path / "worked", "demo", {"seed": 1}, resume=False)
    worked.commit("part-1", {"x": 1})
    assert made.dir.is_dir() and kept.dir.is_dir()
    gone = C.discard_unstarted()
    assert gone == [tmp_path / "new", tmp_path / "old"]
    assert not (tmp_path / "new").exists()                       # made by the run: removed
    assert sorted(p.name for p in (tmp_path / "old").iterdir()) == ["mine.txt"]
    assert worked.done("part-1") == {"x": 1}                     # finished work is kept
    resumed = C.open_run(tmp_path / "worked", "demo", {"seed": 1}, resume=True)
    assert resumed.resumed and C.discard_unstarted() == [] and resumed.dir.is_dir()


def test_demo_refuses_on_board_without_reset_before_its_software_half(emu, one_line):
    out = emu / "demo"
    argv = ["demo", "--mode", "on-board", "--set", "neuron.reset_each_window=false", "--out",
            str(out), "--trials", "2"]
    assert cli.main(argv) == 2
    assert "--mode on-board needs neuron.reset_each_window=true" in one_line()
    assert not out.exists()                 # no software half ran, no checkpoint left


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


def test_compare_no_program_refuses_a_chip_holding_other_weights_before_its_folder(
        emu, capsys, one_line):
    from snan_hil.calibration.testing import grid_weights
    weights = emu / "w.npz"
    np.savez(weights, weights=np.stack([grid_weights(6, 6, seed=s) for s in (1, 2)]))
    assert cli.main(["program-weights", str(weights), "--weight-set", "1", "--port", "emu",
                     "--json"]) == 0
    capsys.readouterr()
    out = emu / "cmp"
    argv = ["compare", "--weights", str(weights), "--no-program", "--port", "emu",
            "--launches", "1", "--scenarios", "hw_noastro", "--no-figure", "--out", str(out),
            "--set", "grid.max_steps=10"]
    assert cli.main([*argv, "--weight-set", "0"]) == 2
    assert "holds other weights" in one_line()
    assert not out.exists()
    assert cli.main([*argv, "--weight-set", "1", "--json"]) == 0   # the corrected command
    assert json.loads(capsys.readouterr().out)["scenarios"]


def test_learn_says_when_its_kernels_compile_first(emu, monkeypatch, capsys):
    from snan_hil.tools.commands import learn
    argv = ["learn", "--arms", "software", "--sessions", "1", "--cycles", "1", "--no-figure",
            "--set", "grid.max_steps=10", "--json"]
    for cached in (False, True):
        monkeypatch.setattr(learn, "kernel_cached", lambda kernel=None, c=cached: c)
        assert cli.main([*argv, "--out", str(emu / f"l{cached}")]) == 0
        err = capsys.readouterr().err
        assert ("compiling the network kernels" in err) is not cached, err
