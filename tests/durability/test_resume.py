"""Long runs are resumable: compare / demo / experiment checkpoints, --resume, reused --out;
a new run's checkpoint with nothing done is removed when the command fails (the corrected
command is not refused for it).

A resumed run must give what an uninterrupted one gives with the same seed (wall times aside,
:func:`snan_hil.host.hil.compare.without_wall_times`); the tests kill real subprocesses.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from snan_hil.crossbar_model import CrossbarArray
from snan_hil.host import checkpoint as C
from snan_hil.host.hil.compare import without_wall_times
from snan_hil.tools import cli

PY = [sys.executable, "-m", "snan_hil.tools.cli"]
SHORT = ["--set", "grid.max_steps=15"]


def compare_argv(weights, out, *extra):
    return ["compare", "--weights", str(weights), "--port", "emu", "--out", str(out),
            "--launches", "2", "--seed", "4", "--json", "--no-figure", *SHORT, *extra]


def results(out):
    return json.loads((Path(out) / "compare.json").read_text())


def comparable(res):
    """Without wall times, and without the chip's serial (two fresh chips, two serials)."""
    view = without_wall_times(res)
    view.pop("board")
    view.get("trained_config_check", {}).pop("weights_path", None)
    return view


def run_cli(argv, env, monkeypatch):
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    return cli.main(argv)


@pytest.fixture(scope="module")
def reference(cli_trained, tmp_path_factory):
    """An uninterrupted compare on a fresh chip (seed 0)."""
    d = tmp_path_factory.mktemp("reference")
    env = dict(os.environ, SNAN_HIL_EMU_STATE=str(d / "chip.npz"),
               XDG_DATA_HOME=str(d / "xdg"))
    done = subprocess.run([*PY, *compare_argv(cli_trained, d / "out")], env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return d


def test_two_identical_compare_runs_give_identical_board_times(cli_trained, reference, tmp_path,
                                                               monkeypatch, capsys):
    """Board times count the frames' encoded length, which depends on the link's first
    sequence number and the board's boot nonce: both are seeded on --port emu."""
    env = {"SNAN_HIL_EMU_STATE": str(tmp_path / "chip.npz"),
           "XDG_DATA_HOME": str(tmp_path / "xdg")}
    assert run_cli(compare_argv(cli_trained, tmp_path / "out"), env, monkeypatch) == 0
    a, b = results(reference / "out"), results(tmp_path / "out")
    rows_a = [r for r in a["launch_rows"] if r["scenario"].startswith("hw_")]
    rows_b = [r for r in b["launch_rows"] if r["scenario"].startswith("hw_")]
    assert rows_a and all(r["virtual_us"] > 0 and r["wire_us"] > 0 for r in rows_a)
    for key in ("virtual_us", "wire_us", "energy_j", "steps", "spikes", "requests"):
        assert [r[key] for r in rows_a] == [r[key] for r in rows_b], key
    assert [p["virtual_s"] for p in a["programming"].values()] == \
        [p["virtual_s"] for p in b["programming"].values()]
    assert a["board"]["board_id"] != b["board"]["board_id"]     # two chips
    assert comparable(a) == comparable(b)


@pytest.mark.parametrize("stop", [signal.SIGKILL, signal.SIGINT])
def test_a_compare_killed_mid_run_resumes_to_the_uninterrupted_results(
        cli_trained, reference, tmp_path, monkeypatch, capsys, stop):
    chip, out = tmp_path / "chip.npz", tmp_path / "out"
    env = {"SNAN_HIL_EMU_STATE": str(chip), "XDG_DATA_HOME": str(tmp_path / "xdg")}
    proc = subprocess.Popen([*PY, *compare_argv(cli_trained, out)], env=dict(os.environ, **env),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = out / "checkpoint" / "unit-set-0.json"
    deadline = time.monotonic() + 300
    while not first.exists():
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.01)
    time.sleep(0.2)                                  # into set 1: programming its cells
    proc.send_signal(stop)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "Traceback" not in err
    names = sorted(p.name for p in (out / "checkpoint").iterdir())
    assert "unit-set-0.json" in names and "unit-set-1.json" not in names, names
    assert not (out / "compare.json").exists()       # no results from half a run
    # without --resume the folder is refused, naming --resume
    capsys.readouterr()
    assert run_cli(compare_argv(cli_trained, out), env, monkeypatch) == 2
    err = capsys.readouterr().err.strip()
    assert "--resume" in err and "\n" not in err
    assert run_cli(compare_argv(cli_trained, out, "--resume"), env, monkeypatch) == 0
    res = results(out)
    assert res["resumed"] is True
    assert comparable(res) == comparable(results(reference / "out"))
    # and the chip ends where the uninterrupted run's chip ended
    mine, theirs = CrossbarArray.load(str(chip)), CrossbarArray.load(str(reference / "chip.npz"))
    assert np.array_equal(mine.state, theirs.state)
    assert mine.noise_state == theirs.noise_state


def test_a_compare_over_the_legacy_protocol_killed_mid_run_resumes_alike(cli_trained, tmp_path,
                                                                         monkeypatch):
    """The journal and the set-boundary chip snapshots work for the existing firmware's line
    protocol too (programming over mode 7/9, launches per window)."""
    legacy = ("--protocol", "legacy")
    ref = tmp_path / "ref"
    ref.mkdir()                             # a chip state's folder must exist (docs/outputs.md)
    env = {"SNAN_HIL_EMU_STATE": str(ref / "chip.npz"), "XDG_DATA_HOME": str(tmp_path / "xdg")}
    assert run_cli(compare_argv(cli_trained, ref / "out", *legacy), env, monkeypatch) == 0
    chip, out = tmp_path / "chip.npz", tmp_path / "out"
    env = {"SNAN_HIL_EMU_STATE": str(chip), "XDG_DATA_HOME": str(tmp_path / "xdg")}
    proc = subprocess.Popen([*PY, *compare_argv(cli_trained, out, *legacy)],
                            env=dict(os.environ, **env), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    kill_when(proc, lambda: (out / "checkpoint" / "unit-set-0.json").exists())
    assert not (out / "checkpoint" / "unit-set-1.json").exists()
    assert run_cli(compare_argv(cli_trained, out, *legacy, "--resume"), env, monkeypatch) == 0
    mine, theirs = results(out), results(ref / "out")
    assert mine["resumed"] is True and mine["mode"] == theirs["mode"] == "per_window"
    assert comparable(mine) == comparable(theirs)
    assert np.array_equal(CrossbarArray.load(str(chip)).state,
                          CrossbarArray.load(str(ref / "chip.npz")).state)


def _replaced(argv, extra):
    """``argv`` with the option of ``extra`` (``[OPT, VALUE]``) given that value instead (an
    option is given once)."""
    out = list(argv)
    i = out.index(extra[0])
    out[i + 1] = extra[1]
    return out


def test_resume_refuses_a_different_run_naming_what_differs(cli_trained, tmp_path, monkeypatch,
                                                            capsys):
    env = {"SNAN_HIL_EMU_STATE": str(tmp_path / "chip.npz"),
           "XDG_DATA_HOME": str(tmp_path / "xdg")}
    out = tmp_path / "out"
    argv = compare_argv(cli_trained, out, "--scenarios", "sw_noastro,sw_astro")
    assert run_cli(argv, env, monkeypatch) == 0
    first = results(out)
    capsys.readouterr()
    for extra, needle in ((["--seed", "5"], "seed: 4 -> 5"),
                          (["--launches", "3"], "launches: 2 -> 3"),
                          (["--set", "grid.max_steps=16", "--accept-config-diff"],
                           "max_steps: 15 -> 16")):
        changed = _replaced(argv, extra) if extra[0] != "--set" else argv + extra
        assert run_cli(changed + ["--resume"], env, monkeypatch) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and "\n" not in err, err
    # the complete run: refused without --resume, rewritten from its checkpoint with it
    assert run_cli(argv, env, monkeypatch) == 2
    assert "complete" in capsys.readouterr().err
    assert run_cli(argv + ["--resume"], env, monkeypatch) == 0
    assert without_wall_times(results(out)) | {"resumed": None} == \
        without_wall_times(first) | {"resumed": None}


def test_resume_keys_the_board_by_its_id_not_its_port(cli_trained, tmp_path, monkeypatch, capsys):
    """The same chip reached through another port string resumes; another chip (another
    board id) is refused naming the board id."""
    chip, other = tmp_path / "chip.npz", tmp_path / "other.npz"
    env = {"SNAN_HIL_EMU_STATE": str(chip), "XDG_DATA_HOME": str(tmp_path / "xdg")}
    out = tmp_path / "out"
    argv = compare_argv(cli_trained, out, "--scenarios", "hw_noastro", "--sets", "1")
    assert run_cli(argv, env, monkeypatch) == 0
    first = results(out)
    capsys.readouterr()
    same = [a if a != "emu" else f"emu://?state={chip}" for a in argv]
    assert same != argv
    assert run_cli(same + ["--resume"], env, monkeypatch) == 0
    capsys.readouterr()
    assert results(out)["board"]["board_id"] == first["board"]["board_id"]
    assert run_cli(["emu", "--reset-chip", "--state", str(other)], env, monkeypatch) == 0
    capsys.readouterr()
    another = [a if a != "emu" else f"emu://?state={other}" for a in argv]
    assert run_cli(another + ["--resume"], env, monkeypatch) == 2
    err = capsys.readouterr().err.strip()
    assert "board_id" in err and "\n" not in err, err


def test_resume_board_key_of_a_board_without_identity_is_its_port():
    from snan_hil.board.identity import BoardIdentity
    from snan_hil.protocol.messages import Info

    def resume_board_key(info, port):
        return BoardIdentity.from_info(info).resume_key(port)
    assert resume_board_key(Info(board_id="MC-1"), "/dev/pts/1") == \
        resume_board_key(Info(board_id="MC-1"), "/dev/pts/0") == {"board_id": "MC-1"}
    assert resume_board_key(Info(board_id="legacy"), "/dev/pts/1") != \
        resume_board_key(Info(board_id="legacy"), "/dev/pts/0")


def test_results_of_an_earlier_run_without_a_checkpoint_are_never_mixed(cli_trained, tmp_path,
                                                                         monkeypatch, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "launches.csv").write_text("old results\n")
    env = {"SNAN_HIL_EMU_STATE": str(tmp_path / "chip.npz")}
    capsys.readouterr()
    for extra in ([], ["--resume"]):
        assert run_cli(compare_argv(cli_trained, out, *extra), env, monkeypatch) == 2
        err = capsys.readouterr().err.strip()
        assert "launches.csv" in err and "\n" not in err
    assert (out / "launches.csv").read_text() == "old results\n"
    assert not (tmp_path / "chip.npz").exists()      # refused before the board was touched
    # results of the command's own kind: an earlier run's, refused also with --force (which
    # only replaces files of another kind)
    from snan_hil.host.hil.compare import LAUNCH_COLUMNS
    (out / "launches.csv").write_text(",".join(LAUNCH_COLUMNS) + "\n")
    for extra in ([], ["--resume"], ["--force"]):
        assert run_cli(compare_argv(cli_trained, out, *extra), env, monkeypatch) == 2
        err = capsys.readouterr().err.strip()
        assert "earlier run" in err and "launches.csv" in err and "\n" not in err, err
    assert not (tmp_path / "chip.npz").exists()


def kill_when(proc, ready, stop=signal.SIGKILL, timeout=300):
    """Send ``stop`` to ``proc`` once ``ready()`` is true (it must still be running)."""
    deadline = time.monotonic() + timeout
    while not ready():
        assert proc.poll() is None, "finished before the kill: " + proc.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.01)
    proc.send_signal(stop)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "Traceback" not in err


def figure_files(folder):
    """A figure's files, the sweep's wall time taken out of the JSON."""
    out = {}
    for f in sorted(folder.iterdir()):
        if f.suffix == ".json":
            data = json.loads(f.read_text())
            data["sweep"].pop("wall_s")
            data["sweep"].pop("executor")        # the resumed part ran on 2 workers
            out[f.name] = data
        elif f.suffix in (".csv", ".md"):
            out[f.name] = f.read_text()
    return out


def test_an_experiment_killed_mid_sweep_resumes_to_the_uninterrupted_figures(tmp_path):
    argv = ["experiment", "fig3", "--trials", "100"]                       # 20 tasks
    assert cli.main([*argv, "--workers", "1", "--out", str(tmp_path / "ref")]) == 0
    out = tmp_path / "out"
    proc = subprocess.Popen([*PY, *argv, "--workers", "1", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    kill_when(proc, lambda: len(list((out / "checkpoint").glob("unit-task-*.json"))) >= 8)
    done = len(list((out / "checkpoint").glob("unit-task-*.json")))
    assert 8 <= done < 20 and not (out / "fig3").exists()
    assert cli.main([*argv, "--out", str(out), "--workers", "2", "--resume"]) == 0
    assert figure_files(out / "fig3") == figure_files(tmp_path / "ref" / "fig3")


def test_a_demo_killed_mid_run_resumes_to_the_uninterrupted_results(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "unused.npz"))
    argv = ["demo", "--trials", "3", "--sets", "2", "--launches", "1"]
    assert cli.main([*argv, "--out", str(tmp_path / "ref")]) == 0
    out = tmp_path / "out"
    proc = subprocess.Popen([*PY, *argv, "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, SNAN_HIL_EMU_STATE=str(tmp_path / "unused.npz")))
    kill_when(proc, lambda: (out / "checkpoint" / "unit-set-0.json").exists())
    assert not (out / "compare.json").exists()
    assert cli.main([*argv, "--out", str(out)]) == 2           # refused without --resume
    assert cli.main([*argv, "--out", str(out), "--resume"]) == 0
    mine, ref = results(out), results(tmp_path / "ref")
    for r in (mine, ref):
        r["training"].pop("wall_s")
        r["weights"].pop("path")
    assert comparable(mine) == comparable(ref)
    assert np.array_equal(CrossbarArray.load(str(out / "chip.npz")).state,
                          CrossbarArray.load(str(tmp_path / "ref" / "chip.npz")).state)
    assert not (tmp_path / "unused.npz").exists()


def test_resume_survives_training_again_with_identical_inputs(cli_trained, tmp_path, monkeypatch,
                                                              capsys):
    """Training again with the same inputs writes a file whose bytes differ (zip time stamps,
    wall time in the provenance) but whose weights are the same: the run keyed by it is
    resumed, not refused; other weights are still refused."""
    import shutil
    env = {"SNAN_HIL_EMU_STATE": str(tmp_path / "chip.npz"),
           "XDG_DATA_HOME": str(tmp_path / "xdg")}
    weights = tmp_path / "w.npz"
    shutil.copy(cli_trained, weights)
    out = tmp_path / "out"
    argv = compare_argv(weights, out, "--scenarios", "sw_noastro")
    assert run_cli(argv, env, monkeypatch) == 0
    def train(seed, *extra):
        return ["train", "--grid", "6", "--start", "18", "--goal", "0", "--sets", "2",
                "--cycles", "2", "--seed", str(seed), "-o", str(weights), "--json", *SHORT,
                *extra]
    before = weights.read_bytes()
    assert run_cli(train(3), env, monkeypatch) == 0
    assert weights.read_bytes() != before          # the file itself differs (its wall time)
    capsys.readouterr()
    assert run_cli(argv + ["--resume"], env, monkeypatch) == 0, capsys.readouterr().err
    # other weights (another training seed) are refused, naming the weights
    assert run_cli(train(4, "--force"), env, monkeypatch) == 0
    capsys.readouterr()
    assert run_cli(argv + ["--resume"], env, monkeypatch) == 2
    assert "weights" in capsys.readouterr().err


def test_a_checkpoint_of_the_compare_before_the_job_runner_resumes_alike(
        cli_trained, reference, tmp_path, monkeypatch):
    """A run stopped by an earlier snan-hil kept the chip as the last finished set left it
    (``board-set-0``, ``layout-set-0.json``); resumed now it gives the uninterrupted results
    (adopt_old_snapshots moves them where the job runner puts a chip back)."""
    from snan_hil.host.checkpoint import RunFolder
    chip, out = tmp_path / "chip.npz", tmp_path / "out"
    env = {"SNAN_HIL_EMU_STATE": str(chip), "XDG_DATA_HOME": str(tmp_path / "xdg")}
    commit = RunFolder.commit

    def commit_then_stop(self, unit, data):
        commit(self, unit, data)
        if unit == "set-0":
            raise KeyboardInterrupt
    monkeypatch.setattr(RunFolder, "commit", commit_then_stop)
    assert run_cli(compare_argv(cli_trained, out), env, monkeypatch) == 130
    monkeypatch.setattr(RunFolder, "commit", commit)
    cp = out / "checkpoint"                  # as the compare before the job runner left it
    saved = cp / "boundaries" / "before-set-1"
    (saved / "chip").rename(cp / "board-set-0")
    (saved / "layout.json").rename(cp / "layout-set-0.json")
    for p in (cp / "boundaries").rglob("*"):
        if p.is_file():
            p.unlink()
    for p in sorted((cp / "boundaries").rglob("*"), reverse=True):
        p.rmdir()
    (cp / "boundaries").rmdir()
    assert run_cli(compare_argv(cli_trained, out, "--resume"), env, monkeypatch) == 0
    assert comparable(results(out)) == comparable(results(reference / "out"))
    assert np.array_equal(CrossbarArray.load(str(chip)).state,
                          CrossbarArray.load(str(reference / "chip.npz")).state)


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


def test_a_resume_refusal_names_the_list_entries_that_differ():
    """A chip group's ports are a list in the run's identity: the refusal names the entry
    that differs (cut at 40 characters, two groups sharing their first port read alike)."""
    from snan_hil.host.checkpoint import differences
    a = ["emu://?state=ma.npz&seed=1", "emu://?state=mb.npz&seed=2"]
    swapped = [a[1], a[0]]
    got = differences({"board": {"group": a}}, {"board": {"group": swapped}})
    assert got == [f"board.group[0]: {a[0]} -> {a[1]}", f"board.group[1]: {a[1]} -> {a[0]}"]
    got = differences({"board": {"group": a}}, {"board": {"group": [*a, "emu://?state=c"]}})
    assert got == ["board.group: 2 entries -> 3"]
    assert differences({"x": [1, 2]}, {"x": [1, 2]}) == []
    assert differences({"x": [{"k": 1}]}, {"x": [{"k": 2}]}) == ["x[0].k: 1 -> 2"]


def test_an_out_folder_of_another_command_is_not_offered_resume(tmp_path):
    """``compare --out`` a ``learn`` run's folder: '--resume' would be refused there (another
    command's run), so the refusal asks for a new folder instead of offering it."""
    from snan_hil.common.errors import UserError
    from snan_hil.host.checkpoint import _check_run
    cdir = tmp_path / "learn-A" / "checkpoint"
    cdir.mkdir(parents=True)
    (cdir / "run.json").write_text(json.dumps({"format": "snan-hil-run/1", "command": "learn",
                                               "status": "complete", "identity": {}}))
    with pytest.raises(UserError) as err:
        _check_run(tmp_path / "learn-A", "compare", resume=False)
    assert "not a compare run; give a new --out folder" in str(err.value)
    assert "--resume" not in str(err.value)
    with pytest.raises(UserError, match="--resume writes them again"):
        _check_run(tmp_path / "learn-A", "learn", resume=False)
