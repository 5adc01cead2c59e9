"""run / compare check the launch model against the training config stored in the weights file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.config.loader import ConfigError
from snan_hil.host.hil.config import HilConfig, load_hil_config
from snan_hil.host.hil.runner import run_scenario
from snan_hil.host.hil.testing import make_weights, small_hil_config
from snan_hil.host.hil.trained_config import (TRAINING_ONLY, TrainedConfigMismatch,
                                              check_trained_config)
from snan_hil.tools import cli


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    d = tmp_path_factory.mktemp("trainedcfg")
    return make_weights(d / "w.npz", sets=1, cycles=2, hil=small_hil_config(max_steps=20))


def _meta(path):
    return load_weight_set(path, 0)[1]


def test_the_training_config_matches_itself(weights):
    check = check_trained_config(_meta(weights), small_hil_config(20), str(weights))
    assert check.stored and check.launch == [] and check.training_only == []
    assert check.notes(str(weights)) == []


def test_a_launch_difference_is_refused_in_one_line_naming_keys_and_flag(weights):
    hil = load_hil_config(None, ["grid.max_steps=20", "astro.a=3", "synapse.w_inh=10"])
    with pytest.raises(TrainedConfigMismatch) as exc:
        check_trained_config(_meta(weights), hil, "w.npz")
    msg = str(exc.value)
    assert "\n" not in msg
    assert "astro.a 6.0 (trained) vs 3.0 (now)" in msg
    trained_w_inh = load_hil_config().model.synapse.w_inh          # the weights' training
    assert f"synapse.w_inh {trained_w_inh} (trained) vs 10.0 (now)" in msg
    assert "--accept-config-diff" in msg
    check = check_trained_config(_meta(weights), hil, "w.npz", accept=True)
    assert [k for k, _a, _b in check.launch] == ["synapse.w_inh", "astro.a"]
    assert check.to_dict()["launch_differences"][1] == {"key": "astro.a", "trained": 6.0,
                                                        "launch": 3.0}
    assert check.accepted and "warning" in check.notes("w.npz")[0]


def test_training_only_differences_are_a_note(weights):
    hil = load_hil_config(None, ["grid.max_steps=20", "stdp.a_plus=0.05", "synapse.w_std=0.2"])
    check = check_trained_config(_meta(weights), hil, "w.npz")
    assert check.launch == []
    assert {k for k, _a, _b in check.training_only} == {"stdp.a_plus", "synapse.w_std"}
    (note,) = check.notes("w.npz")
    assert note.startswith("note:") and "stdp.a_plus 0.04 (trained) vs 0.05 (now)" in note


def test_files_without_a_config_and_old_configs(weights, tmp_path):
    w, meta = load_weight_set(weights, 0)
    npy = tmp_path / "w.npy"
    np.save(npy, w)
    check = check_trained_config(_meta(npy), small_hil_config(20), str(npy))
    assert not check.stored and "holds no training config" in check.notes(str(npy))[0]
    old = dict(meta["config"])                           # before astro.tau_ca_s
    old["astro"] = dict(old["astro"])
    old["astro"]["tau_ca"] = old["astro"].pop("tau_ca_s")
    old["astro"]["tau_ca_unit"] = "s"
    assert check_trained_config({"config": old}, small_hil_config(20), "old.npz").launch == []
    with pytest.raises(ConfigError, match="stored training config: unknown config key astro.x"):
        old["astro"]["x"] = 1
        check_trained_config({"config": old}, small_hil_config(20), "old.npz")


def test_training_only_keys_do_not_change_a_launch(weights):
    """What TRAINING_ONLY claims: changing those keys leaves every launch path unchanged."""
    w, _ = load_weight_set(weights, 0)
    hil = small_hil_config(20)
    changed = {"stdp.a_plus": 0.3, "stdp.a_minus": 0.2, "stdp.tau_plus_ms": 3.0,
               "stdp.k": 4.0, "stdp.w_min": 0.0, "stdp.w_max": 0.95, "stdp.target": "chosen",
               "stdp.pairing": "nearest", "stdp.mode": "window", "synapse.w_mean": 0.7,
               "synapse.w_std": 0.3, "synapse.w_lo": 0.1, "synapse.w_hi": 0.9,
               "synapse.init": "truncate"}
    assert all(any(k.startswith(p) for p in TRAINING_ONLY) for k in changed)
    other = HilConfig(model=hil.model.replace(**changed), task=hil.task)
    for scenario in ("sw_noastro", "sw_astro"):
        a = run_scenario(scenario, w, hil, launches=4, seed=3)
        b = run_scenario(scenario, w, other, launches=4, seed=3)
        assert [L.path for L in a.launches] == [L.path for L in b.launches]
    # and a launch key does change them (the test can fail)
    moved = HilConfig(model=hil.model.replace(**{"synapse.w_inh": 2.0}), task=hil.task)
    a = run_scenario("sw_astro", w, hil, launches=4, seed=3)
    b = run_scenario("sw_astro", w, moved, launches=4, seed=3)
    assert [L.path for L in a.launches] != [L.path for L in b.launches]


def test_run_refuses_then_accepts_with_the_flag(weights, capsys):
    base = ["run", "--scenario", "sw_astro", "--weights", str(weights), "--launches", "2",
            "--json", "--set", "grid.max_steps=20"]
    capsys.readouterr()
    assert cli.main(base + ["--set", "astro.a=3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "astro.a 6.0 (trained) vs 3.0 (now)" in err and "\n" not in err
    assert cli.main(base + ["--set", "astro.a=3", "--accept-config-diff"]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert out["trained_config_check"]["launch_differences"] == [
        {"key": "astro.a", "trained": 6.0, "launch": 3.0}]
    assert out["launch_config"]["astro"]["a"] == 3.0
    assert "warning: launching" in cap.err and "astro.a" in cap.err
    assert cli.main(base) == 0
    assert json.loads(capsys.readouterr().out)["trained_config_check"]["launch_differences"] == []
