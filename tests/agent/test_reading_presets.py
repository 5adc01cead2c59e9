"""Named readings (configs/readings/): the score-chosen defaults and the paper read literally,
on sim and demo (snan_hil.host.reading_presets; docs/model.md "Two named readings")."""

from __future__ import annotations

import json

from snan_hil.host.config import load_config
from snan_hil.host.reading_presets import load_reading, names
from snan_hil.tools.cli import main


def test_the_two_presets_and_what_they_set():
    assert {"scored", "paper-literal"} <= set(names())
    assert load_reading("scored").overrides == {}
    lit = load_reading("paper-literal")
    cfg = load_config(preset="snan-10x10", overrides=lit.assignments())
    assert (cfg.neuron.reset_each_window, cfg.stdp.mode, cfg.stdp.target) == \
        (False, "window", "all")
    d = load_config(preset="snan-10x10")          # the defaults are the scored reading
    assert (d.neuron.reset_each_window, d.stdp.mode, d.stdp.target) == \
        (True, "trial_end", "chosen")


def test_sim_and_demo_say_which_reading_they_ran(tmp_path, capsys):
    assert main(["sim", "--grid", "3", "--no-astro", "--trials", "20", "--reading",
                 "paper-literal", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["reading"] == "paper-literal" and out["config"]["stdp"]["mode"] == "window"
    assert main(["sim", "--grid", "3", "--no-astro", "--trials", "20", "--json"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert plain["reading"] == "scored" and plain["success_rate"] != out["success_rate"]
    assert main(["demo", "--software-only", "--trials", "10", "--reading", "paper-literal",
                 "--out", str(tmp_path / "d")]) == 0
    assert "reading paper-literal" in capsys.readouterr().out
    assert json.loads((tmp_path / "d" / "demo.json").read_text())["reading"] == "paper-literal"


def test_a_preset_and_a_set_that_disagree_are_refused(capsys):
    assert main(["sim", "--grid", "3", "--reading", "paper-literal", "--set",
                 "stdp.mode=off"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--reading paper-literal" in err and len(err.splitlines()) == 1
    assert main(["sim", "--grid", "3", "--reading", "nope"]) == 2
    assert "paper-literal, scored" in capsys.readouterr().err
