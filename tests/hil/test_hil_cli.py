"""train / run / compare through the CLI (in-process emulator, temporary chip); compare
--no-program on a chip holding other weights is refused before its --out is made."""

import csv
import json

import numpy as np
import pytest

from snan_hil.host.intervals import paper_inside, wilson
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.tools import cli

SHORT = ["--set", "grid.max_steps=15"]


@pytest.fixture
def emu_env(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    return tmp_path


def _err_line(capsys):
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    return err


def test_train_writes_the_weights_file(cli_trained, tmp_path, capsys):
    z = np.load(cli_trained)
    assert {"weights", "grid", "start", "goal", "seeds", "config", "cycles"} <= set(z.files)
    assert z["weights"].shape == (2, 36, 36)
    assert list(z["grid"]) == [6, 6] and int(z["start"]) == 18 and int(z["goal"]) == 0
    assert list(z["seeds"]) == [3, 4] and int(z["cycles"]) == 2
    assert json.loads(str(z["config"]))["grid"]["rows"] == 6
    w, meta = load_weight_set(cli_trained, 1)                    # the calibration reader accepts it
    assert meta["seed"] == 4 and meta["n_sets"] == 2 and meta["n_synapses"] == 120
    assert not np.array_equal(z["weights"][0], z["weights"][1])   # one set per seed
    assert not np.array_equal(z["weights"][0], z["initial"][0])   # training changed them
    # deterministic: the same seed gives the same file content; no temporary file left
    again = tmp_path / "again.npz"
    capsys.readouterr()
    assert cli.main(["train", "--sets", "1", "--cycles", "2", "--seed", "3", "-o",
                     str(again), "--json", *SHORT]) == 0
    assert np.array_equal(np.load(again)["weights"][0], z["weights"][0])
    assert [p.name for p in tmp_path.iterdir()] == ["again.npz"]


def test_run_software_json(cli_trained, capsys):
    capsys.readouterr()
    assert cli.main(["run", "--scenario", "sw_astro", "--weights", str(cli_trained),
                     "--weight-set", "1",
                     "--launches", "3", "--seed", "2", "--json", *SHORT]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("scenario", "set", "launches", "path_lengths", "median_steps", "success_rate",
                "seed", "config"):
        assert key in out
    assert out["scenario"] == "sw_astro" and out["set"] == 1 and out["launches"] == 3
    assert len(out["path_lengths"]) == 3 and all(1 <= p <= 15 for p in out["path_lengths"])
    ok = [p for p, s in zip(out["path_lengths"], out["success"]) if s]
    assert out["success_rate"] == pytest.approx(len(ok) / 3)
    if ok:
        assert out["median_steps"] == pytest.approx(float(np.median(ok)))
        assert out["median_steps_ci"][0] <= out["median_steps"] <= out["median_steps_ci"][1]
    assert out["success_rate_ci"] == pytest.approx(list(wilson(len(ok), 3)))
    assert out["launch_config"]["stdp"]["mode"] == "off"         # weights fixed in launches
    assert out["launch_config"]["astro"]["enabled"] is True
    assert out["launch_config"]["grid"]["max_steps"] == 15
    assert out["start"] == 18 and out["goal"] == 0 and out["port"] is None


def test_run_hardware_needs_the_programmed_set(cli_trained, emu_env, capsys):
    base = ["run", "--scenario", "hw_noastro", "--weights", str(cli_trained), "--port", "emu",
            "--launches", "2", "--json", *SHORT]
    capsys.readouterr()
    assert cli.main(base + ["--weight-set", "1"]) == 2         # no layout yet
    err = _err_line(capsys)
    assert "program-weights" in err and "--weight-set 1" in err
    assert not (emu_env / "chip.npz").exists()                  # the port was never opened
    assert cli.main(["program-weights", str(cli_trained), "--weight-set", "0", "--port", "emu",
                     "--json"]) == 0
    capsys.readouterr()
    assert cli.main(base + ["--weight-set", "1"]) == 2         # chip holds set 0, not set 1
    err = _err_line(capsys)
    assert "other weights" in err and "fingerprint" in err
    assert cli.main(base + ["--weight-set", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["scenario"] == "hw_noastro" and out["port"] == "emu"
    assert len(out["path_lengths"]) == 2 and out["read_stats"]["decisions"] == sum(
        out["path_lengths"])
    assert out["board"]["board_us_per_decision"] < out["board"]["virtual_us_per_decision"]
    assert out["board"]["energy_j_per_decision"] > 0


@pytest.mark.parametrize("argv, needle", [
    (["run", "--scenario", "sw_astro", "--weights", "missing.npz"], "does not exist"),
    (["run", "--scenario", "sw_astro", "--weight-set", "7"], "out of range"),
    (["run", "--scenario", "sw_astro", "--launches", "0"], "--launches"),
    (["compare", "--weight-set", "5"], "out of range"),
    # issue 38 item 9: a --mode a software scenario cannot use was ignored silently
    (["run", "--scenario", "sw_astro", "--mode", "on-board"],
     "--mode on-board chooses how the hardware scenarios read the synapses"),
    (["compare", "--scenarios", "sw_noastro,sw_astro", "--mode", "batch"],
     "sw_noastro, sw_astro runs in software"),
    (["train", "--sets", "0", "-o", "x.npz"], "--sets"),
    (["train", "--start", "0", "--goal", "0", "-o", "x.npz"], "start cell 0 equals"),
    (["train", "-o", "x.npy"], ".npz"),
])
def test_bad_input_is_one_line_exit_2(cli_trained, emu_env, capsys, argv, needle):
    if "--weights" not in argv and argv[0] != "train":
        argv = argv + ["--weights", str(cli_trained)]
    argv = [a if a != "x.npz" and a != "x.npy" else str(emu_env / a) for a in argv]
    capsys.readouterr()
    assert cli.main(argv) == 2
    assert needle in _err_line(capsys)


@pytest.mark.parametrize("launches", ["0", "1000"])
def test_demo_refuses_launches_before_any_work(emu_env, capsys, launches):
    out = emu_env / "demo-out"
    assert cli.main(["demo", "--launches", launches, "--out", str(out)]) == 2
    assert "--launches must be in 1..999" in _err_line(capsys)
    assert not out.exists()              # refused before the software comparison and training


def test_compare_writes_consistent_outputs(cli_trained, emu_env, capsys, mcu):
    """A reduced compare (6x6, 2 sets, 2 launches, 15 steps) on each MCU model."""
    out_dir = emu_env / "res"
    capsys.readouterr()
    assert cli.main(["compare", "--weights", str(cli_trained), "--port", "emu", "--mcu", mcu,
                     "--out", str(out_dir), "--launches", "2", "--seed", "4", "--json",
                     *SHORT]) == 0
    printed = json.loads(capsys.readouterr().out)
    names = sorted(p.name for p in out_dir.iterdir())
    assert names == ["checkpoint", "compare.json", "fig10c.png", "launches.csv",
                     "programming", "speed_energy.csv", "summary.csv"]   # no temporary files
    assert sorted(p.name for p in (out_dir / "programming").iterdir()) == [
        "program-set0.json", "program-set1.json"]
    res = json.loads((out_dir / "compare.json").read_text())
    assert res["seed"] == 4 and res["weights"]["set_seeds"] == [3, 4]
    assert res["config"]["model"]["grid"]["max_steps"] == 15
    assert printed["scenarios"] == res["scenarios"]
    rows = list(csv.DictReader((out_dir / "launches.csv").open()))
    assert len(rows) == 4 * 2 * 2 == len(res["launch_rows"])
    for r, j in zip(rows, res["launch_rows"]):
        assert (r["scenario"], int(r["set"]), int(r["steps"])) == (j["scenario"], j["set"],
                                                                  j["steps"])
    summary = list(csv.DictReader((out_dir / "summary.csv").open()))
    assert len(summary) == 8
    for s in summary:
        mine = [int(r["steps"]) for r in rows if r["scenario"] == s["scenario"]
                and r["set"] == s["set"] and r["success"] == "True"]
        want = "" if not mine else float(np.median(mine))
        assert (s["median_steps"] == "" if want == "" else float(s["median_steps"]) == want)
    for s in summary:                              # per set: the Wilson interval in the CSV
        n_ok = sum(r["success"] == "True" for r in rows if r["scenario"] == s["scenario"]
                   and r["set"] == s["set"])
        assert float(s["success_rate_ci_low"]) == pytest.approx(wilson(n_ok, 2)[0])
        assert "Wilson" in s["ci_method"]
    for scen, v in res["scenarios"].items():
        ok = [int(r["steps"]) for r in rows if r["scenario"] == scen and r["success"] == "True"]
        assert v["median_steps"] == (float(np.median(ok)) if ok else None)
        assert v["success_rate_ci"] == pytest.approx(list(wilson(len(ok), 4)))
        assert v["paper_median_steps"] == (7.0 if scen.endswith("_astro") else 14.0)
        assert v["paper_inside"] == paper_inside(v["paper_median_steps"], v["median_steps_ci"])
        assert res["acceptance"][f"paper_inside_{scen}"] == v["paper_inside"]
        if ok:
            assert v["median_steps_ci"][0] <= v["median_steps"] <= v["median_steps_ci"][1]
    hw_rows = [r for r in rows if r["scenario"].startswith("hw_")]
    assert all(float(r["virtual_us"]) > 0 for r in hw_rows)
    # array energy comes from CLOCK: the model integrates it, the C firmware sends 0
    assert all((float(r["energy_j"]) > 0) == (mcu == "model") for r in hw_rows)
    assert all(r["energy_j"] == "" for r in rows if r["scenario"].startswith("sw_"))
    speed = list(csv.DictReader((out_dir / "speed_energy.csv").open()))
    assert len(speed) == len(res["speed_energy"]["rows"]) >= 5
    assert (out_dir / "fig10c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert set(res["acceptance"]) >= {"sw_astro_shortens", "hw_astro_shortens",
                                      "hw_within_20pct_noastro", "hw_within_20pct_astro"}
    from snan_hil.records.history import History          # both sets' programming in the history
    with History.open(emu_env / "chip.history.sqlite", create=False) as db:
        (run,) = db.runs()
        assert run.kind == "hil" and run.command.startswith("snan-hil compare")
        assert run.pulses == sum(v["host_pulses"] for v in res["programming"].values())


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
