"""The ``sim`` and ``demo`` commands: JSON output, plots, exit code 2 on bad input (demo's
checked before its software half runs: --mode on-board without reset, --mcu)."""

import json
import subprocess
import sys

import pytest

from snan_hil.host.intervals import paper_inside, wilson
from snan_hil.tools import cli


def _json(capsys, argv):
    assert cli.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_sim_json_has_the_required_fields(capsys):
    out = _json(capsys, ["sim", "--grid", "3", "--no-astro", "--trials", "40",
                         "--max-steps", "50", "--seed", "4", "--json"])
    for key in ("trials", "success_rate", "median_steps", "mean_steps", "seed", "config",
                "wall_s"):
        assert key in out
    assert out["trials"] == 40 and out["seed"] == 4
    assert 0.0 <= out["success_rate"] <= 1.0
    assert out["config"]["astro"]["enabled"] is False
    assert out["config"]["grid"]["max_steps"] == 50
    # the same command again gives the same numbers (deterministic per seed)
    again = _json(capsys, ["sim", "--grid", "3", "--no-astro", "--trials", "40",
                           "--max-steps", "50", "--seed", "4", "--json"])
    assert again["success_rate"] == out["success_rate"]
    assert again["median_steps"] == out["median_steps"]
    # 95 % intervals with their method, the same again (bootstrap seeded by --seed)
    assert again["median_steps_ci"] == out["median_steps_ci"]
    lo, hi = out["success_rate_ci"]
    assert lo <= out["success_rate"] <= hi
    assert (lo, hi) == pytest.approx(wilson(out["successes"], 40))
    if out["median_steps"] is not None:
        assert out["median_steps_ci"][0] <= out["median_steps"] <= out["median_steps_ci"][1]
    assert "Wilson" in out["ci_method"]["success_rate"]
    assert "bootstrap" in out["ci_method"]["median_steps"]
    # 3x3 has the paper's numbers: inside our intervals or not, and how far
    assert out["paper_success_rate"] == 0.631 and out["paper_median_steps"] == 10.0
    assert out["paper_success_inside"] == (lo <= 0.631 <= hi)
    assert (out["paper_success_distance"] == 0) == out["paper_success_inside"]


def test_sim_json_has_no_paper_fields_for_other_grids(capsys):
    out = _json(capsys, ["sim", "--grid", "4", "--trials", "5", "--max-steps", "20", "--json"])
    assert "paper_success_inside" not in out and out["success_rate_ci"] is not None


def test_sim_grid_and_overrides_select_presets(capsys):
    out = _json(capsys, ["sim", "--grid", "10", "--trials", "3", "--json",
                         "--set", "astro.tau_ca_s=10", "--max-steps", "5"])
    assert out["config"]["name"] == "snan-10x10"
    assert out["config"]["astro"]["tau_ca_s"] == 10.0 and out["config"]["astro"]["a"] == 22.0
    out = _json(capsys, ["sim", "--grid", "4x5", "--trials", "3", "--json",
                         "--max-steps", "5"])
    assert out["grid"] == "4x5"


def test_sim_table_and_plot(tmp_path, capsys):
    png = tmp_path / "sim.png"
    assert cli.main(["sim", "--grid", "3", "--trials", "20", "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    assert "success rate" in text and "median path" in text
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("argv", [
    ["sim", "--trials", "0"],
    ["sim", "--max-steps", "0"],
    ["sim", "--grid", "0"],
    ["sim", "--grid", "abc"],
    ["sim", "--set", "input.p=1.5"],
    ["sim", "--set", "astro.no_such_key=1"],
    ["sim", "--set", "grid.rows=-2"],
    ["sim", "--config", "/no/such/file.yaml"],
    ["demo", "--trials", "0"],
])
def test_bad_input_exits_2_with_one_line(argv, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"snan-hil {argv[0]}: error:") and "\n" not in err


def test_bad_input_has_no_traceback_in_a_real_process(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("grid: {rows: 3, cols: 3}\nastro: {tau_ca_s: 1.2, colour: red}\n")
    proc = subprocess.run([sys.executable, "-m", "snan_hil.tools.cli", "sim", "--config",
                           str(bad)], capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and "astro.colour" in proc.stderr


def test_argparse_errors_exit_2():
    with pytest.raises(SystemExit) as exc:
        cli.main(["sim", "--trials", "many"])
    assert exc.value.code == 2


def test_demo_prints_the_comparison_table(tmp_path, capsys):
    assert cli.main(["demo", "--trials", "5", "--software-only", "--out",
                     str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "10x10" in out and "3x3" in out and "63.1" in out and "362" in out
    # the table is saved, and --json prints it next to the paper's numbers
    rows = (tmp_path / "d" / "software_vs_paper.csv").read_text().splitlines()
    assert rows[0].startswith("grid,astro,trials,success_rate,paper_success_rate") and \
        len(rows) == 5
    assert cli.main(["demo", "--trials", "5", "--software-only", "--out",
                     str(tmp_path / "d"), "--json", "--resume"]) == 0   # the same run again
    data = json.loads(capsys.readouterr().out)
    assert data["format"] == "snan-hil-demo/1" and data["hil"] is None
    paper = {(r["grid"], r["astro"]): (r["paper_success_rate"], r["paper_median_steps"])
             for r in data["software_vs_paper"]}
    assert paper[("3x3", False)] == (0.631, 10.0) and paper[("10x10", True)] == (1.0, 55.0)
    for r in data["software_vs_paper"]:          # every rate with its Wilson interval
        assert r["success_rate_ci"] == pytest.approx(
            wilson(round(r["success_rate"] * r["trials"]), r["trials"]))
        assert r["paper_success_inside"] == paper_inside(r["paper_success_rate"],
                                                         r["success_rate_ci"])
        assert r["paper_median_inside"] == paper_inside(r["paper_median_steps"],
                                                        r["median_steps_ci"])
    header = rows[0].split(",")
    assert {"success_rate_ci_low", "success_rate_ci_high", "median_steps_ci_low",
            "median_steps_ci_high", "paper_success_inside", "ci_method"} <= set(header)
    assert json.loads((tmp_path / "d" / "demo.json").read_text()) == data


def test_demo_runs_the_hardware_chain_into_its_own_folder(tmp_path, monkeypatch, capsys):
    user_chip = tmp_path / "user-chip.npz"
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(user_chip))
    out = tmp_path / "demo"
    assert cli.main(["demo", "--trials", "3", "--sets", "1", "--launches", "1",
                     "--out", str(out), "--set", "synapse.w_inh=20"]) == 0
    text = capsys.readouterr().out
    assert "memristor" in text and "speed and energy" in text
    for name in ("weights.npz", "chip.npz", "chip.layout.json", "compare.json",
                 "summary.csv", "launches.csv", "speed_energy.csv", "fig10c.png",
                 "software_vs_paper.csv", "demo.json"):
        assert (out / name).is_file(), name
    demo = json.loads((out / "demo.json").read_text())
    assert set(demo["hil"]["scenarios"]) == {"sw_noastro", "sw_astro", "hw_noastro", "hw_astro"}
    assert demo["hil"]["paper_median_steps"] == {"without astrocytes": 14.0,
                                                 "with astrocytes": 7.0}
    from snan_hil.records.history import History          # programming + launches: one hil run
    with History.open(out / "chip.history.sqlite", create=False) as db:
        (run,) = db.runs()
        assert run.kind == "hil" and run.status == "complete" and run.pulses > 0
    assert not user_chip.exists()          # the user's default chip is never touched
    # --set reaches the hardware chain too: the weights were trained, and the launches run,
    # in the 6x6 model with the override (after configs/hil-6x6.yaml's own changes)
    import numpy as np
    with np.load(out / "weights.npz", allow_pickle=False) as d:
        trained = json.loads(str(d["config"]))
    assert trained["synapse"]["w_inh"] == 20.0 and trained["grid"]["rows"] == 6
    assert trained["astro"]["a"] == 6.0
    hil = json.loads((out / "compare.json").read_text())["config"]
    assert hil["model"]["synapse"]["w_inh"] == 20.0


def test_demo_refuses_on_board_without_reset_before_its_software_half(emu, one_line):
    out = emu / "demo"
    argv = ["demo", "--mode", "on-board", "--set", "neuron.reset_each_window=false", "--out",
            str(out), "--trials", "2"]
    assert cli.main(argv) == 2
    assert "--mode on-board needs neuron.reset_each_window=true" in one_line()
    assert not out.exists()                 # no software half ran, no checkpoint left


def test_demo_takes_mcu_and_checks_it_before_long_work(emu, one_line, monkeypatch):
    assert cli.main(["demo", "--mcu", "firmware", "--protocol", "legacy", "--out",
                     str(emu / "d"), "--trials", "2"]) == 2
    assert "framed protocol only" in one_line()
    assert not (emu / "d").exists()
    monkeypatch.setenv("SNAN_HIL_FIRMWARE_ELF", str(emu / "missing.elf"))
    assert cli.main(["demo", "--mcu", "firmware", "--out", str(emu / "d2"), "--trials",
                     "2"]) == 2
    assert "missing.elf not found" in one_line() and not (emu / "d2").exists()
