"""The learnt weights with the pulse ledger per cell and cycle, a plain dataset a reviewer can
reload (issue 36 point 4), and the learn command's budget options (point 5)."""

import json

import pytest

from snan_hil.host.hil.learn_dataset import load_dataset
from snan_hil.tools import cli


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    d = tmp_path_factory.mktemp("learn")
    env = pytest.MonkeyPatch()
    env.setenv("SNAN_HIL_EMU_STATE", str(d / "chip.npz"))
    env.setenv("XDG_DATA_HOME", str(d / "data"))
    cells = ";".join(f"{r},{c}" for r in range(2) for c in range(8))
    assert cli.main(["characterize", "--port", "emu", "--cells", cells, "--repeats", "1",
                     "--model", str(d / "m.json"), "--json"]) == 0
    assert cli.main(["learn", "--port", "emu", "--sessions", "2", "--cycles", "3",
                     "--arms", "device,chip", "--model", str(d / "m.json"), "--out",
                     str(d / "out"), "--pulse-budget", "40", "--cell-budget", "4",
                     "--pace", "0.5", "--no-figure", "--json"]) == 0
    env.undo()
    return d / "out"


def test_the_dataset_reloads_and_agrees_with_the_ledger(run, capsys):
    capsys.readouterr()
    doc = json.loads((run / "learn.json").read_text())
    data = load_dataset(run)
    ledger = doc["ledger"]
    assert data.pulses("") == ledger["total"]
    assert data.pulses("learn") == sum(r["set"] + r["reset"] for r in ledger["rows"]
                                       if r["stage"].startswith("learn"))
    per_cell = {}
    for r in data.cell_ledger:
        per_cell[f"{r['row']},{r['col']}"] = per_cell.get(f"{r['row']},{r['col']}", 0) + \
            r["set"] + r["reset"]
    assert per_cell == ledger["per_cell"]
    # every learning row names the synapse its cell holds
    assert all(r["pre"] is not None for r in data.cell_ledger if r["stage"] == "learn")
    # weights: both arms, every cycle, every synapse; the chip arm's final reads on cycle 3
    n_syn = len(doc["synapses"])
    for arm in ("device", "chip"):
        rows = [r for r in data.weights if r["arm"] == arm]
        assert len(rows) == 2 * 3 * n_syn
    chip_final = [r["w_final"] for r in data.weights if r["arm"] == "chip" and r["cycle"] == 3]
    sessions = doc["arms"]["chip"]["sessions"]
    assert chip_final == pytest.approx(sessions[0]["weights"] + sessions[1]["weights"],
                                       abs=1e-5)
    assert all(r["row"] is not None for r in data.weights if r["arm"] == "chip")


def test_the_budget_holds_per_session_and_cell(run):
    doc = json.loads((run / "learn.json").read_text())
    assert doc["config"]["budget"]["session_pulses"] == 40
    data = load_dataset(run)
    for k, s in enumerate(doc["arms"]["chip"]["sessions"]):
        assert sum(s["pulses"]) <= 40
        assert max(data.per_cell(k).values(), default=0) <= 4
        assert s["max_cell_pulses"] <= 4
    for s in doc["arms"]["device"]["sessions"]:
        assert sum(s["pulses"]) <= 40 and s["max_cell_pulses"] <= 4


def test_bad_budget_options_are_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    for argv, text in ((["--pulse-budget", "0"], "session_pulses"),
                       (["--threshold-steps", "0.1"], "threshold_steps"),
                       (["--pace", "1.5"], "plan_share")):
        assert cli.main(["learn", "--port", "emu", "--arms", "software", "--out",
                         str(tmp_path / "o"), *argv]) == 2
        err = capsys.readouterr().err
        assert text in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
