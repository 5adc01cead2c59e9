"""A chip group as one instrument (issue 35): one network over several chips, each decision
window on the chip of its input neuron (calibration/chip_group.py, host/hil/group_window.py,
lab/group_run.py, ``compare --group``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from snan_hil.calibration.chip_group import (MIN_SPARE_ROWS, merge_programming, min_chips,
                                             plan_group, window_chips)
from snan_hil.calibration.layout import Layout, LayoutError, share_synapses
from snan_hil.calibration.weights_io import grid_synapses
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model import CrossbarArray
from snan_hil.host.hil.compare import without_wall_times
from snan_hil.tools import cli

PY = [sys.executable, "-m", "snan_hil.tools.cli"]
SHORT = ["--set", "grid.max_steps=15"]
ARRAY = (32, 8)


@pytest.mark.parametrize("chips", [2, 3])
def test_every_decision_window_of_the_10x10_network_touches_one_chip(chips):
    plan = plan_group((10, 10), ARRAY, chips)
    every = sorted(p for share in plan.shares for p in share)
    assert every == list(range(100))                      # each input neuron on one chip
    for pre in range(100):
        assert len(window_chips(plan, pre)) == 1
    counts = [plan.synapses(k) for k in range(chips)]
    assert sum(counts) == len(grid_synapses(10, 10)) == 360
    assert max(counts) - min(counts) <= 4                 # as even as whole neurons allow
    for k in range(chips):
        assert plan.block_rows(k) <= ARRAY[0] - MIN_SPARE_ROWS
        assert plan.spare_cells(k) >= MIN_SPARE_ROWS * ARRAY[1]


def test_a_group_too_small_for_the_network_is_refused_in_one_line():
    assert min_chips((10, 10), ARRAY) == 2
    with pytest.raises(UserError) as exc:
        plan_group((10, 10), ARRAY, 1)
    line = str(exc.value)
    assert "360 synapses" in line and "at least 2 chips" in line and "\n" not in line
    with pytest.raises(UserError, match="leave a chip empty|would hold none"):
        plan_group((2, 2), ARRAY, 5)


def test_a_share_layout_holds_only_its_input_neurons_and_round_trips():
    plan = plan_group((10, 10), ARRAY, 3)
    lay = Layout.place((10, 10), ARRAY, pres=plan.shares[1])
    assert sorted((s.pre, s.post) for s in lay.synapses) == \
        share_synapses(10, 10, plan.shares[1]) == lay.pairs()
    assert lay.block_rows == plan.block_rows(1)
    back = Layout.from_dict(json.loads(json.dumps(lay.to_dict())))
    assert back.pres == plan.shares[1] and back.pairs() == lay.pairs()
    whole = Layout.place((10, 10), (64, 8))
    assert whole.pres is None and "pres" not in whole.to_dict()
    broken = lay.to_dict()
    broken["synapses"] = broken["synapses"][:-1]          # a synapse of the share missing
    with pytest.raises(LayoutError, match="its 32 input neurons"):
        Layout.from_dict(broken)
    with pytest.raises(LayoutError, match="need 45 rows.*--group"):
        Layout.place((10, 10), ARRAY)                     # the whole network on one chip


def test_the_group_backend_refuses_an_input_neuron_on_two_chips():
    from snan_hil.host.agent import environment, synapse_tables
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.group_window import GroupMotorNeurons
    from snan_hil.calibration.readchain import ReadChain
    from snan_hil.protocol.board import MEMRICORE
    cfg = load_hil_config().launch_config(True)
    nbr, _ = synapse_tables(environment(cfg), cfg)
    chain = ReadChain.nominal(MEMRICORE)
    lays = [Layout.place((6, 6), ARRAY, pres=tuple(range(0, 20))),
            Layout.place((6, 6), ARRAY, pres=tuple(range(18, 36)))]
    for lay in lays:
        lay.read_chain = chain
    with pytest.raises(UserError, match="input neuron 18 is on chip 0 and chip 1"):
        GroupMotorNeurons([(object(), lays[0]), (object(), lays[1])], nbr, cfg)  # type: ignore
    with pytest.raises(UserError, match="on no chip"):
        GroupMotorNeurons([(object(), lays[0])], nbr, cfg)  # type: ignore


def test_merge_programming_sums_the_chips_and_keeps_each():
    a = {"cells": 60, "ok": 60, "failed": 0, "pulses_total": 100, "virtual_s": 1.5,
         "all_ok": True, "pulses_match": True}
    b = {**a, "ok": 59, "failed": 1, "pulses_total": 50, "all_ok": False}
    m = merge_programming([a, b])
    assert (m["cells"], m["ok"], m["failed"], m["pulses_total"], m["virtual_s"]) == \
        (120, 119, 1, 150, 3.0)
    assert m["all_ok"] is False and m["pulses_match"] is True and m["chips"] == [a, b]
    assert m["relocated"] is None                          # not in the chips' summaries


# -- compare --group on two emulated chips ---------------------------------------------------

def group_argv(weights, out, d, *extra):
    ports = f"emu://?state={d / 'a.npz'},emu://?state={d / 'b.npz'}"
    return ["compare", "--weights", str(weights), "--group", ports, "--out", str(out),
            "--launches", "2", "--seed", "4", "--json", "--no-figure", *SHORT, *extra]


def env_of(d: Path) -> dict[str, str]:
    return {"XDG_DATA_HOME": str(d / "xdg")}


@pytest.fixture(scope="module")
def grouped(cli_trained, tmp_path_factory):
    """An uninterrupted comparison of the 6x6 weights over two fresh emulated chips."""
    d = tmp_path_factory.mktemp("group")
    env = dict(os.environ, **env_of(d))
    env.pop("SNAN_HIL_PORT", None)
    done = subprocess.run([*PY, *group_argv(cli_trained, d / "out", d)], env=env,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    return d


def results(out: Path) -> dict:
    return json.loads((out / "compare.json").read_text())


@pytest.mark.timeout(600)          # the fixture's run: ~1 min on a quiet machine
def test_compare_over_a_group_programs_each_share_and_runs_each_window_on_its_chip(grouped):
    res = results(grouped / "out")
    plan = res["group"]["plan"]
    assert [c["pres"] for c in plan["chips"]] == [[0, 17], [18, 35]]
    chips = res["group"]["chips"]
    assert len({c["board_id"] for c in chips}) == 2       # two chips, not one twice
    for k, name in enumerate(("a", "b")):
        lay = Layout.load(grouped / f"{name}.layout.json")
        assert lay.pres == tuple(range(plan["chips"][k]["pres"][0],
                                       plan["chips"][k]["pres"][1] + 1))
        assert all(s.ok for s in lay.synapses)
        for s in (0, 1):
            assert (grouped / "out" / "programming" / f"program-set{s}-chip{k}.json").is_file()
    for prog in res["programming"].values():
        assert prog["all_ok"] and len(prog["chips"]) == 2
        assert prog["cells"] == 120
    cp = grouped / "out" / "checkpoint"
    for s in (0, 1):
        rec = json.loads((cp / f"unit-set-{s}.json").read_text())["data"]
        for r in rec["results"]:
            if not r["scenario"].startswith("hw_"):
                continue
            per_chip = r["read_stats"]["decisions_per_chip"]
            decisions = sum(L["decisions"] for L in r["launches"])
            assert sum(per_chip) == decisions and all(n > 0 for n in per_chip)
            # route 18 -> 0 starts on chip 1 (neurons 18-35) and ends on chip 0
    hw = [r for r in res["launch_rows"] if r["scenario"].startswith("hw_")]
    sw = {(r["scenario"][3:], r["set"], r["launch"]): r["steps"]
          for r in res["launch_rows"] if r["scenario"].startswith("sw_")}
    same = sum(r["steps"] == sw[(r["scenario"][3:], r["set"], r["launch"])] for r in hw)
    assert same >= len(hw) // 2          # the crossbar follows the software launch by launch
    assert all(r["virtual_us"] > 0 for r in hw)


@pytest.mark.timeout(600)
def test_each_chip_records_the_run_and_its_pulses_in_its_own_history(grouped):
    from snan_hil.records import history as H
    for name in ("a", "b"):
        with H.History.open(grouped / f"{name}.history.sqlite", create=False) as db:
            runs = [r for r in db.runs(kind="hil") if r.status == "complete"]
            assert runs and runs[-1].pulses > 0


@pytest.mark.parametrize("argv,needle", [
    (["--boards", "emu,emu://?state=x.npz"], "--group makes several chips one instrument"),
    (["--no-program"], "--no-program"),
    (["--scenarios", "sw_astro"], "has none"),
    (["--mode", "batch"], "on-board decision windows"),
    (["--protocol", "legacy"], "legacy"),
])
def test_bad_group_options_are_one_line_before_any_chip(cli_trained, tmp_path, monkeypatch,
                                                        capsys, argv, needle):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert cli.main(group_argv(cli_trained, tmp_path / "out", tmp_path, *argv)) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "a.npz").exists() and not (tmp_path / "out").exists()


@pytest.mark.parametrize("ports,needle", [
    ("emu://?state=A.npz", "two ports or more"),
    ("emu://?state=A.npz,emu://?state=A.npz", "same board"),
])
def test_a_group_of_one_chip_or_one_chip_twice_is_refused(cli_trained, tmp_path, monkeypatch,
                                                          capsys, ports, needle):
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    monkeypatch.chdir(tmp_path)
    argv = ["compare", "--weights", str(cli_trained), "--group", ports, "--out", "out",
            *SHORT]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "--group" in err and "\n" not in err
    assert not (tmp_path / "A.npz").exists()


def test_a_smaller_crossbar_needs_more_chips_and_the_line_says_how_many():
    """The emulated chips are all 32 x 8 (no option makes a smaller one), so the refusal of
    a group too small for its network is checked on the plan the job makes from the chips'
    INFO (CompareJob._plan_group -> GroupBench.plan -> plan_group)."""
    assert plan_group((10, 10), (24, 8), 2).block_rows(0) == 23      # 23 + 1 spare row
    with pytest.raises(UserError, match="do not fit 2 chip.*give at least 3 chips"):
        plan_group((10, 10), (22, 8), 2)


@pytest.mark.timeout(600)
def test_a_group_compare_killed_mid_run_resumes_to_the_uninterrupted_results(
        cli_trained, grouped, tmp_path, monkeypatch, capsys):
    """Killed (SIGKILL) in set 1, resumed: every chip put back as it was before set 1 (its
    boundary), so the results and the chips are those of the uninterrupted run."""
    out = tmp_path / "out"
    env = dict(os.environ, **env_of(tmp_path))
    env.pop("SNAN_HIL_PORT", None)
    proc = subprocess.Popen([*PY, *group_argv(cli_trained, out, tmp_path)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = out / "checkpoint" / "unit-set-0.json"
    deadline = time.monotonic() + 600
    while not first.exists():
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.01)
    time.sleep(0.2)                                  # into set 1
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=120)
    assert proc.returncode != 0
    assert not (out / "checkpoint" / "unit-set-1.json").exists()
    for k, v in env_of(tmp_path).items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("SNAN_HIL_PORT", raising=False)
    assert cli.main(group_argv(cli_trained, out, tmp_path, "--resume")) == 0
    mine, ref = results(out), results(grouped / "out")
    assert mine["resumed"] is True

    def view(res: dict) -> dict:
        v = without_wall_times(res)
        for key in ("board", "group", "port", "session", "run", "programming"):
            v.pop(key, None)
        v.get("trained_config_check", {}).pop("weights_path", None)
        return v
    assert view(mine) == view(ref)
    for name in ("a", "b"):            # every chip ends where the uninterrupted run's ended
        a = CrossbarArray.load(str(tmp_path / f"{name}.npz"))
        b = CrossbarArray.load(str(grouped / f"{name}.npz"))
        assert np.array_equal(a.state, b.state)


@pytest.mark.timeout(600)
def test_run_over_the_group_launches_the_set_the_chips_hold_as_compare_did(
        cli_trained, grouped, monkeypatch, capsys):
    """After the comparison the chips hold set 1: ``run --group`` launches it with the same
    windows (the same launches as the comparison's, launch by launch); set 0 is refused in
    one line naming how to program the group."""
    monkeypatch.setenv("XDG_DATA_HOME", str(grouped / "xdg"))
    monkeypatch.delenv("SNAN_HIL_PORT", raising=False)
    ports = f"emu://?state={grouped / 'a.npz'},emu://?state={grouped / 'b.npz'}"
    argv = ["run", "--weights", str(cli_trained), "--group", ports, "--scenario", "hw_astro",
            "--launches", "2", "--seed", "4", "--json", *SHORT]
    capsys.readouterr()
    assert cli.main([*argv, "--weight-set", "1"]) == 0
    got = json.loads(capsys.readouterr().out)
    ref = [r["steps"] for r in results(grouped / "out")["launch_rows"]
           if r["scenario"] == "hw_astro" and r["set"] == 1]
    assert got["path_lengths"] == ref
    assert got["read_stats"]["chips"] == 2
    from snan_hil.records import history as H

    def runs() -> list[int]:
        out = []
        for name in ("a", "b"):
            with H.History.open(grouped / f"{name}.history.sqlite", create=False) as db:
                out.append(len(db.runs()))
        return out
    before = runs()
    assert cli.main([*argv, "--weight-set", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds other weights" in err and "compare" in err and "--group" in err
    assert "\n" not in err
    assert runs() == before                 # a refusal in the plan: no run in any history


def test_the_program_hint_of_run_group_names_the_model_options():
    """``run --group``'s refusal names the ``compare --group`` that programs the chips: with
    the ``--config``/``--set`` of the run (the 10x10 config), else the command it prints is
    refused as 'trained with another model'."""
    import argparse
    from snan_hil.tools.commands.run import _program_hint
    args = argparse.Namespace(weights="w10.npz", set_index=1, scenario="hw_astro",
                              config="configs/hil-10x10.yaml",
                              overrides=["grid.max_steps=15"])
    hint = _program_hint(args, ["emu://?state=a.npz", "emu://?state=b.npz"])
    assert ("snan-hil compare --weights w10.npz --config configs/hil-10x10.yaml --set "
            "grid.max_steps=15 --weight-set 1 --group") in hint, hint
    args.config, args.overrides = None, []
    assert "--config" not in _program_hint(args, ["a", "b"])
